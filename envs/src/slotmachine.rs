//! The slotmachine of the paper's proof of concept.
//!
//! Four reels of six faces. An action picks, for each reel, a fraction `k / bins` of a full
//! turn (`bins^4` actions; reel `i`'s `k` is digit `i` of the action in base `bins`); the reel
//! advances `floor(6 * k / bins)` faces. The state is the face position of every reel
//! (one-hot over `6^4`, index `sum_i pos_i * 6^i`). Reward: for each face value showing on at
//! least `threshold` reels, count x value. Reels start at random positions; the episode is
//! truncated after `horizon` steps.

use jsae_env_spec::SlotmachineConfig;
use jsae_spaces::{ActionSpace, StateBatch, StateSpace};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::{ActionRef, Env, Step};

/// The face values of each reel.
pub const REELS: [[u32; 6]; 4] = [
    [2, 3, 6, 7, 0, 4],
    [3, 4, 6, 2, 1, 7],
    [1, 6, 5, 3, 4, 7],
    [5, 1, 4, 2, 6, 0],
];
const FACES: u32 = 6;

/// The slotmachine.
#[derive(Debug, Clone)]
pub struct Slotmachine {
    config: SlotmachineConfig,
    state_space: StateSpace,
    action_space: ActionSpace,
    pos: [u32; 4],
    steps: u32,
}

impl Slotmachine {
    /// A slotmachine with the given settings.
    pub fn new(config: SlotmachineConfig) -> Self {
        let n = (config.bins as usize).pow(4);
        let state_space = if config.factored {
            StateSpace::Categorical {
                sizes: vec![FACES as usize; 4],
            }
        } else {
            StateSpace::discrete((FACES as usize).pow(4))
        };
        Self {
            config,
            state_space,
            action_space: ActionSpace::Discrete { n },
            pos: [0; 4],
            steps: 0,
        }
    }

    /// Faces advanced on each reel by `action`.
    pub fn advances(&self, action: u32) -> [u32; 4] {
        let b = self.config.bins;
        let mut a = action;
        let mut out = [0; 4];
        for adv in &mut out {
            *adv = FACES * (a % b) / b;
            a /= b;
        }
        out
    }

    /// Reel positions.
    pub fn positions(&self) -> [u32; 4] {
        self.pos
    }

    /// Sets reel positions (for tests).
    pub fn set_positions(&mut self, pos: [u32; 4]) {
        self.pos = pos.map(|p| p % FACES);
    }

    /// The payout of the values showing at `pos`.
    pub fn payout(&self, pos: [u32; 4]) -> f64 {
        let mut counts = [0u32; 8];
        for (reel, &p) in REELS.iter().zip(&pos) {
            counts[reel[p as usize] as usize] += 1;
        }
        counts
            .iter()
            .enumerate()
            .filter(|&(_, &c)| c >= self.config.threshold)
            .map(|(value, &c)| f64::from(c) * value as f64)
            .sum()
    }
}

impl Env for Slotmachine {
    fn state_space(&self) -> &StateSpace {
        &self.state_space
    }

    fn action_space(&self) -> &ActionSpace {
        &self.action_space
    }

    fn has_success(&self) -> bool {
        false
    }

    fn reset(&mut self, rng: &mut ChaCha8Rng) {
        self.pos = std::array::from_fn(|_| rng.random_range(0..FACES));
        self.steps = 0;
    }

    fn step(&mut self, action: ActionRef<'_>) -> Step {
        if let ActionRef::Discrete(a) = action {
            let adv = self.advances(a);
            for (p, d) in self.pos.iter_mut().zip(adv) {
                *p = (*p + d) % FACES;
            }
        }
        self.steps += 1;
        Step {
            reward: self.payout(self.pos),
            terminated: false,
            truncated: self.steps >= self.config.horizon,
            success: false,
            lost: false,
        }
    }

    fn push_state(&self, out: &mut StateBatch) {
        if let StateBatch::Categorical { data, .. } = out {
            if self.config.factored {
                data.extend_from_slice(&self.pos);
            } else {
                let index = self.pos.iter().rev().fold(0, |acc, &p| acc * FACES + p);
                data.push(index);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn reel_arithmetic_and_action_digits() {
        let s = Slotmachine::new(SlotmachineConfig::default());
        assert_eq!(s.action_space().num_discrete(), Some(4096));
        // k = 0..7 of 8 bins advance floor(6k/8) faces
        let advances: Vec<u32> = (0..8).map(|k| s.advances(k)[0]).collect();
        assert_eq!(advances, vec![0, 0, 1, 2, 3, 3, 4, 5]);
        // digit i of the action (base 8) drives reel i
        assert_eq!(s.advances(7 * 512 + 4 * 64 + 2 * 8 + 1), [0, 1, 3, 5]);
    }

    #[test]
    fn payout_counts_values_showing_at_threshold() {
        let mut s = Slotmachine::new(SlotmachineConfig::default());
        // faces: reel0 pos2 = 6, reel1 pos2 = 6, reel2 pos1 = 6, reel3 pos4 = 6
        assert_eq!(s.payout([2, 2, 1, 4]), 24.0);
        // 7, 7, 7 and 0: 3 x 7
        assert_eq!(s.payout([3, 5, 5, 5]), 21.0);
        // values 2, 3, 1, 5: nothing pairs
        assert_eq!(s.payout([0, 0, 0, 0]), 0.0);
        // two pairs: 3,3 and 4? reel0 pos1 = 3, reel1 pos0 = 3, reel2 pos4 = 4, reel3 pos2 = 4
        assert_eq!(s.payout([1, 0, 4, 2]), 2.0 * 3.0 + 2.0 * 4.0);
        s.config.threshold = 3;
        assert_eq!(s.payout([1, 0, 4, 2]), 0.0);
    }

    #[test]
    fn steps_wrap_reels_and_the_horizon_truncates() {
        let mut s = Slotmachine::new(SlotmachineConfig {
            horizon: 3,
            ..Default::default()
        });
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        s.reset(&mut rng);
        s.set_positions([5, 5, 5, 5]);
        let step = s.step(ActionRef::Discrete(7 + 7 * 8 + 7 * 64 + 7 * 512));
        assert_eq!(s.positions(), [4, 4, 4, 4]);
        assert_eq!(step.reward, s.payout([4, 4, 4, 4]));
        assert!(!s.step(ActionRef::Discrete(0)).truncated);
        let last = s.step(ActionRef::Discrete(0));
        assert!(last.truncated && !last.terminated);
        let mut batch = StateBatch::empty(s.state_space());
        s.push_state(&mut batch);
        assert_eq!(
            batch,
            StateBatch::Categorical {
                factors: 4,
                data: vec![4, 4, 4, 4]
            }
        );
        // the unfactored state: one index over all 6^4 positions
        let mut one_hot = Slotmachine::new(SlotmachineConfig {
            factored: false,
            ..Default::default()
        });
        one_hot.set_positions([4, 1, 0, 2]);
        let mut batch = StateBatch::empty(one_hot.state_space());
        one_hot.push_state(&mut batch);
        assert_eq!(
            batch,
            StateBatch::Categorical {
                factors: 1,
                data: vec![4 + 6 + 2 * 216]
            }
        );
    }

    #[test]
    fn resets_are_seeded() {
        let starts = |seed| {
            let mut s = Slotmachine::new(SlotmachineConfig::default());
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            (0..5)
                .map(|_| {
                    s.reset(&mut rng);
                    s.positions()
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(starts(7), starts(7));
        assert_ne!(starts(7), starts(8));
    }
}
