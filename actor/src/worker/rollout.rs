//! A rollout: every active environment stepped `rollout_steps` times with one batched
//! inference per step ([`ActorWorker::collect`]), into the transitions the embedder learns
//! from, one fragment per environment for the learner, and the recording's rows.

use jsae_envs::Step;
use jsae_record::RecordedSteps;
use jsae_wire::{ActionBatch, EpisodeStat, RolloutFragment, StateBatch, TransitionBatch};

use super::{ActorWorker, Rollout, Running};

impl ActorWorker {
    /// Steps every active environment `rollout_steps` times.
    pub fn collect(&mut self, rollout_steps: usize) -> Rollout {
        let k = self.active;
        let acting = self.acting();
        let record_transitions =
            self.recording || self.config.algo.representation().needs_embedder();
        let mut recorded = self.recording.then(|| RecordedSteps {
            policy_version: if acting {
                self.weights.policy_version().unwrap_or(0)
            } else {
                0
            },
            embedding_version: if acting { self.embedding_version() } else { 0 },
            ..RecordedSteps::default()
        });
        let x_dim = self.weights.acting_policy().input_dim();
        let mut transitions = TransitionBatch {
            actor_id: self.id,
            states: StateBatch::empty(&self.states),
            actions: ActionBatch::empty(&self.actions),
            rewards: Vec::new(),
            next_states: StateBatch::empty(&self.states),
            terminated: Vec::new(),
        };
        let mut fragments = self.empty_fragments(rollout_steps, x_dim);
        let mut b = StepBuffers::new(self, k);
        for _ in 0..rollout_steps {
            b.policy_actions.clear();
            b.env_actions.clear();
            b.logp.clear();
            if acting {
                self.policy_inputs(&self.current, &mut b.x);
                self.weights.acting_policy().act(
                    &b.x,
                    self.weights.prior(),
                    false,
                    &mut self.rng,
                    &mut b.policy_actions,
                    &mut b.logp,
                );
                self.env_actions(&b.policy_actions, &mut b.env_actions);
            } else {
                self.random_actions(k, &mut b.env_actions);
            }
            b.next.clear();
            b.cut_states.clear();
            b.cut_envs.clear();
            b.after.clear();
            self.envs.step(&b.env_actions, &mut b.steps);
            let mut out = StepOutputs {
                record_transitions,
                transitions: &mut transitions,
                fragments: &mut fragments,
                recorded: recorded.as_mut(),
            };
            for i in 0..k {
                self.take_step(i, acting, x_dim, &mut b, &mut out);
            }
            if acting && !b.cut_envs.is_empty() {
                self.policy_inputs(&b.cut_states, &mut b.cut_x);
                for (j, &i) in b.cut_envs.iter().enumerate() {
                    fragments[i]
                        .truncated_next_x
                        .extend_from_slice(&b.cut_x[j * x_dim..(j + 1) * x_dim]);
                }
            }
            std::mem::swap(&mut self.current, &mut b.after);
            self.env_steps += k as u64;
        }
        if acting {
            self.policy_inputs(&self.current, &mut b.x);
            for (i, f) in fragments.iter_mut().enumerate() {
                f.last_next_x
                    .extend_from_slice(&b.x[i * x_dim..(i + 1) * x_dim]);
                f.actor_env_steps = self.env_steps;
            }
            // an environment lost at every step of the rollout has nothing to send
            fragments.retain(|f| !f.rewards.is_empty());
        } else {
            fragments.clear();
        }
        Rollout {
            transitions,
            fragments,
            recorded,
        }
    }

    /// One fragment per active environment, empty, for a rollout of `rollout_steps`.
    fn empty_fragments(&self, rollout_steps: usize, x_dim: usize) -> Vec<RolloutFragment> {
        let head_space = self.weights.acting_policy().head().action_space();
        (0..self.active)
            .map(|i| RolloutFragment {
                actor_id: self.id,
                env_index: i as u32,
                policy_version: self.weights.policy_version().unwrap_or(0),
                embedding_version: self.embedding_version(),
                actor_env_steps: 0,
                x_dim,
                x: Vec::with_capacity(rollout_steps * x_dim),
                actions: ActionBatch::empty(&head_space),
                logp: Vec::with_capacity(rollout_steps),
                rewards: Vec::with_capacity(rollout_steps),
                terminated: Vec::with_capacity(rollout_steps),
                truncated: Vec::with_capacity(rollout_steps),
                truncated_next_x: Vec::new(),
                last_next_x: Vec::new(),
                episodes: Vec::new(),
                actor_incarnation: self.incarnation,
                visit_keys: Vec::new(),
            })
            .collect()
    }

    /// Environment `i`'s step just taken (`b.steps[i]`): its episode's running return and
    /// end (a truncated one's last state kept for bootstrapping, the environment reset), its
    /// transition, its fragment's row and its recording row.
    fn take_step(
        &mut self,
        i: usize,
        acting: bool,
        x_dim: usize,
        b: &mut StepBuffers,
        out: &mut StepOutputs<'_>,
    ) {
        let step = b.steps[i];
        if step.lost {
            self.lose_step(i, acting, x_dim, b, out);
            return;
        }
        self.envs.push_state(i, &mut b.next);
        let visit = if acting {
            self.visit_key(&b.next, i)
        } else {
            None
        };
        let run = &mut self.running[i];
        if let Some(r) = out.recorded.as_mut() {
            r.env_index.push(i as u32);
            r.episode.push(self.episodes[i]);
            r.step.push(run.len);
            r.truncated.push(step.truncated);
        }
        run.ret += step.reward;
        run.len += 1;
        let mut finished = None;
        if step.terminated || step.truncated {
            finished = Some(EpisodeStat {
                ret: run.ret,
                length: run.len,
                success: self.envs.has_success().then_some(step.success),
            });
            *run = Running::default();
            self.episodes[i] += 1;
            if step.truncated {
                b.cut_states.push_row_of(&b.next, i);
                b.cut_envs.push(i);
            }
            self.envs.reset(i, &mut self.env_rngs[i]);
        }
        self.envs.push_state(i, &mut b.after);
        if out.record_transitions {
            let t = &mut *out.transitions;
            t.states.push_row_of(&self.current, i);
            t.actions.push_row_of(&b.env_actions, i);
            t.rewards.push(step.reward as f32);
            t.next_states.push_row_of(&b.next, i);
            t.terminated.push(step.terminated);
        }
        let f = &mut out.fragments[i];
        if let Some(ep) = finished {
            f.episodes.push(ep);
        }
        if acting {
            f.x.extend_from_slice(&b.x[i * x_dim..(i + 1) * x_dim]);
            f.actions.push_row_of(&b.policy_actions, i);
            f.logp.push(b.logp[i]);
            f.rewards.push(step.reward as f32);
            f.visit_keys.extend(visit);
            f.terminated.push(step.terminated);
            f.truncated.push(step.truncated);
        }
    }
}

impl ActorWorker {
    /// Environment `i` was lost before its step ([`Step::lost`]): no transition and no
    /// fragment row; its episode ends truncated at the state it was in (the fragment's last
    /// row, where it is this rollout's and still open, is marked truncated with that state
    /// to bootstrap from) and is not counted; the environment starts another episode.
    fn lose_step(
        &mut self,
        i: usize,
        acting: bool,
        x_dim: usize,
        b: &mut StepBuffers,
        out: &mut StepOutputs<'_>,
    ) {
        // the step's next state is the state it was in: later rows of `b.next` stay aligned
        b.next.push_row_of(&self.current, i);
        let f = &mut out.fragments[i];
        let open = f.terminated.last() == Some(&false) && f.truncated.last() == Some(&false);
        if acting && open {
            if let Some(last) = f.truncated.last_mut() {
                *last = true;
            }
            f.truncated_next_x
                .extend_from_slice(&b.x[i * x_dim..(i + 1) * x_dim]);
        }
        if self.running[i].len > 0 {
            tracing::warn!(
                "actor {}: environment {i} was lost {} steps into its episode; the episode \
                 ends truncated there and is not counted",
                self.id,
                self.running[i].len
            );
        }
        self.running[i] = Running::default();
        self.episodes[i] += 1;
        self.envs.reset(i, &mut self.env_rngs[i]);
        self.envs.push_state(i, &mut b.after);
    }
}

/// The buffers a rollout reuses from step to step.
struct StepBuffers {
    /// Policy inputs of the current states, `[k, x_dim]`.
    x: Vec<f32>,
    policy_actions: ActionBatch,
    logp: Vec<f32>,
    env_actions: ActionBatch,
    /// The states the step reached.
    next: StateBatch,
    /// The last states of the episodes the step truncated, and their environments.
    cut_states: StateBatch,
    cut_x: Vec<f32>,
    cut_envs: Vec<usize>,
    /// The states after the step: `next`, or the reset state where an episode ended.
    after: StateBatch,
    steps: Vec<Step>,
}

impl StepBuffers {
    fn new(worker: &ActorWorker, k: usize) -> Self {
        let head_space = worker.weights.acting_policy().head().action_space();
        Self {
            x: Vec::new(),
            policy_actions: ActionBatch::empty(&head_space),
            logp: Vec::with_capacity(k),
            env_actions: ActionBatch::empty(&worker.actions),
            next: StateBatch::empty(&worker.states),
            cut_states: StateBatch::empty(&worker.states),
            cut_x: Vec::new(),
            cut_envs: Vec::new(),
            after: StateBatch::empty(&worker.states),
            steps: vec![Step::default(); k],
        }
    }
}

/// Where a rollout's steps go.
struct StepOutputs<'a> {
    /// Whether the transitions are kept (for the embedder or the recording).
    record_transitions: bool,
    transitions: &'a mut TransitionBatch,
    fragments: &'a mut [RolloutFragment],
    recorded: Option<&'a mut RecordedSteps>,
}
