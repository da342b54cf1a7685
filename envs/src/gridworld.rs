//! The gridworld of the paper's proof of concept, with solid walls.
//!
//! `n` actuators are unit vectors at angles `2*pi*k/n`; action `i` is an n-bit mask whose
//! motion is the sum of its active actuators, scaled so the longest motion over all actions
//! has norm 1. A step is `substeps` sub-steps of `substep_len * motion`; a sub-step whose
//! segment would touch a wall or leave `[0,1]^2` ends the step where it is (a collision).
//! Walls are solid: the whole segment is tested, not only its end point.
//!
//! Rewards: `step_reward` every step, plus `collision_reward` on a collision, plus
//! `goal_reward` when a sub-step's segment touches the goal (the episode terminates there).
//! The time limit `max_steps` truncates.

use jsae_env_spec::GridworldConfig;
use jsae_spaces::{ActionSpace, StateBatch, StateSpace};
use rand_chacha::ChaCha8Rng;

use super::geometry::Rect;
use super::{ActionRef, Env, Step};

/// The two walls forming the L.
const WALLS: [Rect; 2] = [
    Rect::new(0.0, 0.5, 0.375, 0.4),
    Rect::new(0.5, 0.525, 0.375, 0.75),
];
/// The goal region.
const GOAL: Rect = Rect::new(0.125, 0.175, 0.625, 0.675);
const START: [f64; 2] = [0.3, 0.1];

/// Motion of every action (the rule lives with the settings, so services that never step
/// the gridworld measure embeddings against the same motions).
pub use jsae_env_spec::gridworld_action_motions as action_motions;

/// Bin of a coordinate in `[0, 1]`: `min(floor(bins * c), bins - 1)`, never wrapping.
pub fn bin(c: f64, bins: u32) -> u32 {
    ((c * bins as f64).floor().max(0.0) as u32).min(bins - 1)
}

/// The gridworld, continuous or discrete state.
#[derive(Debug, Clone)]
pub struct Gridworld {
    config: GridworldConfig,
    discrete: bool,
    motions: Vec<[f64; 2]>,
    state_space: StateSpace,
    action_space: ActionSpace,
    pos: [f64; 2],
    steps: u32,
}

impl Gridworld {
    /// A gridworld; `discrete` bins the state into `bins x bins` one-hot states.
    pub fn new(config: GridworldConfig, discrete: bool) -> Self {
        let motions = action_motions(config.actuators);
        let state_space = if discrete {
            StateSpace::discrete((config.bins * config.bins) as usize)
        } else {
            StateSpace::Real { dim: 2 }
        };
        let action_space = ActionSpace::Discrete { n: motions.len() };
        Self {
            config,
            discrete,
            motions,
            state_space,
            action_space,
            pos: START,
            steps: 0,
        }
    }

    /// The agent's position.
    pub fn position(&self) -> [f64; 2] {
        self.pos
    }

    /// Places the agent (for tests and plots).
    pub fn set_position(&mut self, pos: [f64; 2]) {
        self.pos = pos;
    }

    /// Motion of every action.
    pub fn motions(&self) -> &[[f64; 2]] {
        &self.motions
    }

    /// Index of the discrete state of a position: `bin(x) * bins + bin(y)`.
    pub fn state_index(&self, pos: [f64; 2]) -> u32 {
        let b = self.config.bins;
        bin(pos[0], b) * b + bin(pos[1], b)
    }

    fn blocked(a: [f64; 2], b: [f64; 2]) -> bool {
        let outside = !(0.0..=1.0).contains(&b[0]) || !(0.0..=1.0).contains(&b[1]);
        outside || WALLS.iter().any(|w| w.hit_by_segment(a, b))
    }
}

impl Env for Gridworld {
    fn state_space(&self) -> &StateSpace {
        &self.state_space
    }

    fn action_space(&self) -> &ActionSpace {
        &self.action_space
    }

    fn has_success(&self) -> bool {
        true
    }

    fn reset(&mut self, _rng: &mut ChaCha8Rng) {
        self.pos = START;
        self.steps = 0;
    }

    fn step(&mut self, action: ActionRef<'_>) -> Step {
        let motion = match action {
            ActionRef::Discrete(a) => self.motions.get(a as usize).copied().unwrap_or([0.0; 2]),
            ActionRef::Continuous(_) => [0.0; 2],
        };
        let c = &self.config;
        let mut reward = c.step_reward;
        let mut reached = false;
        for _ in 0..c.substeps {
            let next = [
                self.pos[0] + c.substep_len * motion[0],
                self.pos[1] + c.substep_len * motion[1],
            ];
            if Self::blocked(self.pos, next) {
                reward += c.collision_reward;
                break;
            }
            let touches_goal = GOAL.hit_by_segment(self.pos, next);
            self.pos = next;
            if touches_goal {
                reached = true;
                reward += c.goal_reward;
                break;
            }
        }
        self.steps += 1;
        Step {
            reward,
            terminated: reached,
            truncated: !reached && self.steps >= c.max_steps,
            success: reached,
            lost: false,
        }
    }

    fn push_state(&self, out: &mut StateBatch) {
        match out {
            StateBatch::Categorical { data, .. } if self.discrete => {
                data.push(self.state_index(self.pos))
            }
            StateBatch::Real { data, .. } => {
                data.push(self.pos[0] as f32);
                data.push(self.pos[1] as f32);
            }
            StateBatch::Categorical { .. } => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn world() -> Gridworld {
        Gridworld::new(GridworldConfig::default(), false)
    }

    /// The action whose motion best follows the direction `(dx, dy)`.
    fn action_towards(g: &Gridworld, dx: f64, dy: f64) -> u32 {
        let norm = dx.hypot(dy);
        let mut best = (f64::MIN, 0);
        for (i, m) in g.motions().iter().enumerate() {
            let score = (m[0] * dx + m[1] * dy) / norm - 0.5 * (m[0] * dy - m[1] * dx).abs();
            if score > best.0 {
                best = (score, i as u32);
            }
        }
        best.1
    }

    #[test]
    fn motions_are_scaled_to_unit_maximum() {
        let m = action_motions(9);
        assert_eq!(m.len(), 512);
        let longest = m.iter().map(|v| v[0].hypot(v[1])).fold(0.0, f64::max);
        assert!((longest - 1.0).abs() < 1e-12);
        assert_eq!(m[0], [0.0, 0.0]);
        // actuator 0 alone points along +x
        let single = m[1];
        assert!(single[0] > 0.0 && single[1].abs() < 1e-12);
    }

    #[test]
    fn the_horizontal_wall_is_solid_for_a_full_step() {
        let mut g = world();
        // just below the 0.025-thick wall: a sub-step of 0.045 would jump over it
        g.set_position([0.2, 0.36]);
        let up = action_towards(&g, 0.0, 1.0);
        let s = g.step(ActionRef::Discrete(up));
        assert!(
            g.position()[1] < 0.375,
            "agent tunnelled to {:?}",
            g.position()
        );
        assert!((s.reward - (-0.01 - 0.05)).abs() < 1e-12);
        assert!(!s.terminated && !s.truncated);
    }

    #[test]
    fn the_vertical_wall_blocks_from_the_right() {
        let mut g = world();
        g.set_position([0.54, 0.5]);
        let left = action_towards(&g, -1.0, 0.0);
        g.step(ActionRef::Discrete(left));
        assert!(
            g.position()[0] > 0.525,
            "agent crossed to {:?}",
            g.position()
        );
    }

    #[test]
    fn the_border_stops_the_step_without_wrapping() {
        let mut g = world();
        g.set_position([0.01, 0.1]);
        let left = action_towards(&g, -1.0, 0.0);
        let s = g.step(ActionRef::Discrete(left));
        assert_eq!(g.position(), [0.01, 0.1]);
        assert!(s.reward < -0.01);
        // a free step costs only the step penalty and moves 4 sub-steps
        let mut g = world();
        let right = action_towards(&g, 1.0, 0.0);
        let motion = g.motions()[right as usize];
        let s = g.step(ActionRef::Discrete(right));
        assert!((s.reward + 0.01).abs() < 1e-12);
        assert!((g.position()[0] - (0.3 + 4.0 * 0.045 * motion[0])).abs() < 1e-12);
    }

    #[test]
    fn reaching_the_goal_terminates_with_the_goal_reward() {
        let mut g = world();
        g.set_position([0.15, 0.60]);
        let up = action_towards(&g, 0.0, 1.0);
        let s = g.step(ActionRef::Discrete(up));
        assert!(s.terminated && s.success && !s.truncated);
        assert!((s.reward - 0.99).abs() < 1e-12);
    }

    /// The action whose full step lands closest to `target` (walls ignored).
    fn greedy_action(g: &Gridworld, target: [f64; 2]) -> u32 {
        let p = g.position();
        let dist =
            |m: &[f64; 2]| (p[0] + 0.18 * m[0] - target[0]).hypot(p[1] + 0.18 * m[1] - target[1]);
        let mut best = (f64::MAX, 0);
        for (i, m) in g.motions().iter().enumerate() {
            if dist(m) < best.0 {
                best = (dist(m), i as u32);
            }
        }
        best.1
    }

    #[test]
    fn the_way_around_the_l_reaches_the_goal_and_the_time_limit_truncates() {
        let mut g = world();
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        g.reset(&mut rng);
        let waypoints = [[0.7, 0.1], [0.7, 0.85], [0.15, 0.85], [0.15, 0.65]];
        let (mut total, mut steps, mut w) = (0.0, 0, 0);
        let mut last = None;
        while steps < 40 {
            let p = g.position();
            if w + 1 < waypoints.len()
                && (p[0] - waypoints[w][0]).hypot(p[1] - waypoints[w][1]) < 0.05
            {
                w += 1;
            }
            let s = g.step(ActionRef::Discrete(greedy_action(&g, waypoints[w])));
            total += s.reward;
            steps += 1;
            last = Some(s);
            if s.terminated {
                break;
            }
        }
        let last = last.expect("stepped");
        assert!(
            last.terminated && last.success,
            "ended at {:?}",
            g.position()
        );
        assert!(steps < 25 && total > 0.75, "{steps} steps, return {total}");

        // the straight way up is blocked by the solid wall: never reaches the goal
        let mut g = world();
        g.reset(&mut rng);
        let mut last = None;
        for _ in 0..150 {
            last = Some(g.step(ActionRef::Discrete(greedy_action(&g, [0.15, 0.65]))));
            assert!(!last.expect("step").terminated);
        }
        let last = last.expect("150 steps");
        assert!(last.truncated && !last.terminated);
    }

    #[test]
    fn binning_clamps_at_the_edges_and_never_wraps() {
        assert_eq!(bin(0.0, 40), 0);
        assert_eq!(bin(0.0249, 40), 0);
        assert_eq!(bin(0.025, 40), 1);
        assert_eq!(bin(1.0, 40), 39);
        assert_eq!(bin(-1e-9, 40), 0);
        let g = Gridworld::new(GridworldConfig::default(), true);
        assert_eq!(g.state_index([0.0, 0.0]), 0);
        assert_eq!(g.state_index([1.0, 1.0]), 1599);
        assert_eq!(g.state_index([0.3, 0.1]), 12 * 40 + 4);
        let mut batch = StateBatch::empty(g.state_space());
        g.push_state(&mut batch);
        assert_eq!(
            batch,
            StateBatch::Categorical {
                factors: 1,
                data: vec![484]
            }
        );
    }
}
