//! Generalised advantage estimation with terminated and truncated kept apart.

/// One environment's consecutive steps, as GAE needs them.
#[derive(Debug, Clone, Copy)]
pub struct GaeStep {
    /// Reward.
    pub reward: f32,
    /// `V(s_t)`.
    pub value: f32,
    /// `V` of the real next state (the time-limit state for a truncated step, the state
    /// after the fragment for its last step). Ignored when `terminated`.
    pub next_value: f32,
    /// `s_{t+1}` is terminal: its value is 0.
    pub terminated: bool,
    /// The episode ended here (terminated or truncated): advantages do not flow back across.
    pub episode_end: bool,
}

/// Advantages and returns (`advantage + value`) of one environment's steps.
///
/// `delta_t = r_t + gamma * V(s_{t+1}) * (1 - terminated_t) - V(s_t)`;
/// `A_t = delta_t + gamma * lambda * (1 - episode_end_t) * A_{t+1}`, with `A` after the last
/// step 0 (its tail is bootstrapped through `next_value`).
pub fn gae(steps: &[GaeStep], gamma: f32, lambda: f32) -> (Vec<f32>, Vec<f32>) {
    let mut adv = vec![0.0; steps.len()];
    let mut next_adv = 0.0;
    for (t, s) in steps.iter().enumerate().rev() {
        let bootstrap = if s.terminated {
            0.0
        } else {
            gamma * s.next_value
        };
        let delta = s.reward + bootstrap - s.value;
        let carry = if s.episode_end {
            0.0
        } else {
            gamma * lambda * next_adv
        };
        adv[t] = delta + carry;
        next_adv = adv[t];
    }
    let returns = adv.iter().zip(steps).map(|(a, s)| a + s.value).collect();
    (adv, returns)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(
        reward: f32,
        value: f32,
        next_value: f32,
        terminated: bool,
        truncated: bool,
    ) -> GaeStep {
        GaeStep {
            reward,
            value,
            next_value,
            terminated,
            episode_end: terminated || truncated,
        }
    }

    #[test]
    fn matches_hand_computed_values() {
        // gamma 0.9, lambda 0.5; three steps, no episode end, tail bootstrapped with 4.0
        let steps = [
            step(1.0, 2.0, 3.0, false, false),
            step(0.0, 3.0, 1.0, false, false),
            step(2.0, 1.0, 4.0, false, false),
        ];
        let (adv, ret) = gae(&steps, 0.9, 0.5);
        // deltas: 1 + 2.7 - 2 = 1.7; 0 + 0.9 - 3 = -2.1; 2 + 3.6 - 1 = 4.6
        // A2 = 4.6; A1 = -2.1 + 0.45 * 4.6 = -0.03; A0 = 1.7 + 0.45 * -0.03 = 1.6865
        let want = [1.6865, -0.03, 4.6];
        for (a, w) in adv.iter().zip(want) {
            assert!((a - w).abs() < 1e-5, "{adv:?}");
        }
        assert!((ret[0] - 3.6865).abs() < 1e-5 && (ret[2] - 5.6).abs() < 1e-5);
    }

    #[test]
    fn termination_zeroes_the_bootstrap_and_truncation_keeps_it() {
        // same step ends the episode: terminated -> delta = r - V; truncated -> r + g V' - V
        let term = gae(
            &[
                step(1.0, 0.5, 10.0, true, false),
                step(5.0, 0.0, 0.0, false, false),
            ],
            0.9,
            0.5,
        );
        assert!((term.0[0] - 0.5).abs() < 1e-6, "{:?}", term.0);
        let trunc = gae(
            &[
                step(1.0, 0.5, 10.0, false, true),
                step(5.0, 0.0, 0.0, false, false),
            ],
            0.9,
            0.5,
        );
        assert!((trunc.0[0] - 9.5).abs() < 1e-6, "{:?}", trunc.0);
        // and in neither case does the next episode's advantage (5.0) leak back
        assert!((term.0[1] - 5.0).abs() < 1e-6);
    }
}
