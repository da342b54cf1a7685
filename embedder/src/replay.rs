//! A bounded buffer of raw transitions. The push side ([`Replay::push`]) and the sample
//! side ([`Replay::sample`], [`Replay::window`]) are separate: the embedder's ingest path
//! only pushes, its trainer only samples.

use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace, TransitionBatch};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// A minibatch of `(s, a, s')`.
#[derive(Debug, Clone)]
pub struct Minibatch {
    /// States.
    pub states: StateBatch,
    /// Actions.
    pub actions: ActionBatch,
    /// Next states.
    pub next_states: StateBatch,
}

/// Ring buffer of transitions; when full the oldest are overwritten.
#[derive(Debug, Clone)]
pub struct Replay {
    capacity: usize,
    states: StateBatch,
    actions: ActionBatch,
    next_states: StateBatch,
    len: usize,
    head: usize,
    pushed: u64,
    overwritten: u64,
    state_width: usize,
    action_width: usize,
}

fn write_row_u32(dst: &mut [u32], src: &[u32], row: usize, w: usize, src_row: usize) {
    dst[row * w..(row + 1) * w].copy_from_slice(&src[src_row * w..(src_row + 1) * w]);
}

fn write_row_f32(dst: &mut [f32], src: &[f32], row: usize, w: usize, src_row: usize) {
    dst[row * w..(row + 1) * w].copy_from_slice(&src[src_row * w..(src_row + 1) * w]);
}

fn set_state_row(dst: &mut StateBatch, src: &StateBatch, row: usize, src_row: usize, w: usize) {
    match (dst, src) {
        (StateBatch::Categorical { data, .. }, StateBatch::Categorical { data: s, .. }) => {
            write_row_u32(data, s, row, w, src_row)
        }
        (StateBatch::Real { data, .. }, StateBatch::Real { data: s, .. }) => {
            write_row_f32(data, s, row, w, src_row)
        }
        _ => {}
    }
}

fn set_action_row(dst: &mut ActionBatch, src: &ActionBatch, row: usize, src_row: usize, w: usize) {
    match (dst, src) {
        (ActionBatch::Discrete(d), ActionBatch::Discrete(s)) => d[row] = s[src_row],
        (ActionBatch::Continuous { data, .. }, ActionBatch::Continuous { data: s, .. }) => {
            write_row_f32(data, s, row, w, src_row)
        }
        _ => {}
    }
}

impl Replay {
    /// An empty buffer for the given spaces.
    pub fn new(capacity: usize, states: &StateSpace, actions: &ActionSpace) -> Self {
        Self {
            capacity,
            states: StateBatch::empty(states),
            actions: ActionBatch::empty(actions),
            next_states: StateBatch::empty(states),
            len: 0,
            head: 0,
            pushed: 0,
            overwritten: 0,
            state_width: states.stored_len(),
            action_width: actions.stored_len(),
        }
    }

    /// Transitions held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds nothing.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Transitions ever pushed.
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    /// Transitions dropped to make room.
    pub fn overwritten(&self) -> u64 {
        self.overwritten
    }

    /// Adds a (validated) batch.
    pub fn push(&mut self, batch: &TransitionBatch) {
        for i in 0..batch.len() {
            if self.len < self.capacity {
                self.states.push_row_of(&batch.states, i);
                self.actions.push_row_of(&batch.actions, i);
                self.next_states.push_row_of(&batch.next_states, i);
                self.len += 1;
            } else {
                let (sw, aw) = (self.state_width, self.action_width);
                set_state_row(&mut self.states, &batch.states, self.head, i, sw);
                set_action_row(&mut self.actions, &batch.actions, self.head, i, aw);
                set_state_row(&mut self.next_states, &batch.next_states, self.head, i, sw);
                self.head = (self.head + 1) % self.capacity;
                self.overwritten += 1;
            }
            self.pushed += 1;
        }
    }

    /// The transitions at the given positions (`0..len`).
    pub fn gather(&self, rows: &[usize]) -> Minibatch {
        let mut mb = Minibatch {
            states: self.states.clone_empty(),
            actions: self.actions.clone_empty(),
            next_states: self.next_states.clone_empty(),
        };
        for &r in rows {
            mb.states.push_row_of(&self.states, r);
            mb.actions.push_row_of(&self.actions, r);
            mb.next_states.push_row_of(&self.next_states, r);
        }
        mb
    }

    /// `n` transitions drawn uniformly with replacement.
    pub fn sample(&self, n: usize, rng: &mut ChaCha8Rng) -> Minibatch {
        let rows: Vec<usize> = (0..n)
            .map(|_| rng.random_range(0..self.len.max(1)))
            .collect();
        self.gather(&rows)
    }
}

trait CloneEmpty {
    fn clone_empty(&self) -> Self;
}

impl CloneEmpty for StateBatch {
    fn clone_empty(&self) -> Self {
        match self {
            StateBatch::Categorical { factors, .. } => StateBatch::Categorical {
                factors: *factors,
                data: Vec::new(),
            },
            StateBatch::Real { dim, .. } => StateBatch::Real {
                dim: *dim,
                data: Vec::new(),
            },
        }
    }
}

impl CloneEmpty for ActionBatch {
    fn clone_empty(&self) -> Self {
        match self {
            ActionBatch::Discrete(_) => ActionBatch::Discrete(Vec::new()),
            ActionBatch::Continuous { dim, .. } => ActionBatch::Continuous {
                dim: *dim,
                data: Vec::new(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn batch(values: &[u32]) -> TransitionBatch {
        TransitionBatch {
            actor_id: 0,
            states: StateBatch::Categorical {
                factors: 1,
                data: values.to_vec(),
            },
            actions: ActionBatch::Discrete(values.to_vec()),
            rewards: vec![0.0; values.len()],
            next_states: StateBatch::Categorical {
                factors: 1,
                data: values.iter().map(|v| v + 1).collect(),
            },
            terminated: vec![false; values.len()],
        }
    }

    #[test]
    fn the_oldest_transitions_are_overwritten_when_full() {
        let mut r = Replay::new(
            3,
            &StateSpace::discrete(10),
            &ActionSpace::Discrete { n: 10 },
        );
        r.push(&batch(&[0, 1]));
        r.push(&batch(&[2, 3, 4]));
        assert_eq!((r.len(), r.pushed(), r.overwritten()), (3, 5, 2));
        let all = r.gather(&[0, 1, 2]);
        let mut held = match all.states {
            StateBatch::Categorical { data, .. } => data,
            StateBatch::Real { .. } => vec![],
        };
        held.sort();
        assert_eq!(held, vec![2, 3, 4]);
        assert_eq!(all.actions.len(), 3);
    }
}
