//! [`RemotePool`]: an actor's environments hosted by worker processes. Each of the pool's
//! environments (its slots) lives on one worker at a time; a step sends every worker the
//! actions of its slots in one command and waits for every answer. A worker that goes away
//! or breaks the protocol loses its slots' steps ([`Step::lost`]): their episodes end
//! truncated, and each slot's next episode starts on a worker still there (one that offered
//! spare environments, else the least loaded, which then hosts one more). With no worker
//! left the pool waits for one to connect.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use jsae_envs::{ActionRef, EnvPool, GymSpace, Step};
use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace, pb};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use tonic::Status;

use crate::codec::{SpaceCodec, check_step_reply};
use crate::host::{EnvHost, Event, Lobby};
use crate::workers::WorkerProcesses;

/// The longest a worker may take to answer one command before it counts as gone.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(120);
/// How long the pool's first episodes wait for workers offering all its environments
/// before starting on those connected (the others then host more).
pub const GATHER_TIMEOUT: Duration = Duration::from_secs(20);

#[derive(Debug)]
struct Worker {
    name: String,
    offered: u32,
    /// Environments it hosts (numbered from 0): the next slot placed on it gets this number.
    hosted: u32,
    commands: tokio::sync::mpsc::Sender<Result<pb::EnvCommand, Status>>,
}

#[derive(Debug)]
struct Slot {
    /// The worker and its environment number.
    home: Option<(u64, u32)>,
    /// The current state, one row.
    state: StateBatch,
    /// The first state of the next episode, sent with the step that ended the last one.
    next_start: Option<StateBatch>,
}

/// The environments of one actor, on its workers.
#[derive(Debug)]
pub struct RemotePool {
    codec: SpaceCodec,
    states: StateSpace,
    actions: ActionSpace,
    lobby: Arc<Lobby>,
    events: mpsc::Receiver<(u64, Event)>,
    workers: BTreeMap<u64, Worker>,
    /// `len + 1` slots: the last is the evaluation's.
    slots: Vec<Slot>,
    seq: u64,
    gathered: bool,
    stop: Arc<AtomicBool>,
    /// The workers this process started, started again when they exit.
    supervised: Option<Arc<Mutex<WorkerProcesses>>>,
    /// Why no environment can step any more (the pool then stops).
    failure: Option<String>,
    /// The largest reward magnitude taken (`ppo.max_abs_reward`, at most 1e9).
    max_abs_reward: f64,
}

/// One worker's share of a command: its environment numbers and the slots they are.
struct Share {
    command: pb::EnvCommand,
    slots: Vec<usize>,
}

impl RemotePool {
    /// A pool of `envs` environments (and the evaluation's) of `env_id`, whose workers must
    /// describe `observation` and `action`; and the service they connect to.
    pub fn new(
        env_id: &str,
        (observation, action): (GymSpace, GymSpace),
        envs: usize,
    ) -> Result<(Self, EnvHost), String> {
        observation.check("observation")?;
        action.check("action")?;
        let actions = action
            .action_space()
            .ok_or_else(|| format!("{} has too many actions", action.describe()))?;
        let states = observation.state_space();
        let (events_tx, events) = mpsc::channel();
        let lobby = Arc::new(Lobby::new(
            env_id.to_string(),
            (observation.clone(), action.clone()),
            events_tx,
        ));
        let zero = zero_state(&states);
        let slots = (0..=envs)
            .map(|_| Slot {
                home: None,
                state: zero.clone(),
                next_start: None,
            })
            .collect();
        let pool = Self {
            codec: SpaceCodec::new(observation),
            states,
            actions,
            lobby: lobby.clone(),
            events,
            workers: BTreeMap::new(),
            slots,
            seq: 0,
            gathered: false,
            stop: Arc::new(AtomicBool::new(false)),
            supervised: None,
            failure: None,
            max_abs_reward: crate::codec::MAX_ABS_REWARD,
        };
        Ok((pool, EnvHost::new(lobby)))
    }

    /// A flag that, set, makes the pool stop waiting for workers (its steps are then lost).
    pub fn stopper(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// Starts again the workers of `workers` that exit; where one cannot run again and no
    /// worker is left, the pool fails ([`jsae_envs::EnvPool::failure`]).
    pub fn supervise(&mut self, workers: Arc<Mutex<WorkerProcesses>>) {
        self.supervised = Some(workers);
    }

    /// Rewards beyond `max` (the learner's `ppo.max_abs_reward`) are refused here, where the
    /// worker sending them is told.
    pub fn set_max_abs_reward(&mut self, max: f64) {
        self.max_abs_reward = max.min(crate::codec::MAX_ABS_REWARD);
    }

    /// Checks the started workers: the reason when one will not run again.
    fn check_workers(&mut self) -> Result<(), String> {
        match &self.supervised {
            Some(w) => w
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .supervise(),
            None => Ok(()),
        }
    }

    /// Workers connected now.
    pub fn workers(&self) -> usize {
        self.workers.len()
    }

    /// Takes in the workers that joined.
    fn admit(&mut self) {
        let joined = std::mem::take(
            &mut *self
                .lobby
                .joined
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        );
        for j in joined {
            self.workers.insert(
                j.id,
                Worker {
                    name: j.name,
                    offered: j.envs,
                    hosted: 0,
                    commands: j.commands,
                },
            );
        }
    }

    /// Waits until a worker is connected (the first time, until the workers offer every
    /// slot or [`GATHER_TIMEOUT`] has passed with one); false when stopped.
    fn wait_for_workers(&mut self) -> bool {
        let start = Instant::now();
        let mut said = false;
        loop {
            self.admit();
            self.drain_events();
            let offered: usize = self.workers.values().map(|w| w.offered as usize).sum();
            let enough = if self.gathered {
                !self.workers.is_empty()
            } else {
                offered >= self.slots.len() - 1
                    || (!self.workers.is_empty() && start.elapsed() >= GATHER_TIMEOUT)
            };
            if enough {
                self.gathered = true;
                return true;
            }
            if self.stop.load(Ordering::Relaxed) || self.failure.is_some() {
                return false;
            }
            if let Err(reason) = self.check_workers()
                && self.workers.is_empty()
            {
                tracing::error!("{reason}; no environment worker is left");
                self.failure = Some(reason);
                return false;
            }
            if !said && start.elapsed() > Duration::from_secs(2) {
                tracing::info!(
                    "waiting for environment workers: {} connected, offering {offered} of the {} \
                     environments",
                    self.workers.len(),
                    self.slots.len() - 1
                );
                said = true;
            }
            let joined = self
                .lobby
                .joined
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            if joined.is_empty() {
                let _ = self
                    .lobby
                    .arrived
                    .wait_timeout(joined, Duration::from_millis(100));
            }
        }
    }

    /// Takes in the workers that joined and reads the events of idle ones (one that went
    /// away is dropped).
    fn drain_events(&mut self) {
        // a started worker that exited is started again (it joins as a spare); one that will
        // not run again fails the pool only once no worker is left (`wait_for_workers`)
        if let Err(reason) = self.check_workers() {
            tracing::debug!("{reason}");
        }
        self.admit();
        while let Ok((id, event)) = self.events.try_recv() {
            match event {
                Event::Gone(reason) => self.drop_worker(id, &reason, false),
                Event::Reply(_) => self.drop_worker(id, "it answered a command not sent", true),
            }
        }
    }

    /// Forgets a worker; its slots' next steps are lost. `refuse`: its stream ends with
    /// INVALID_ARGUMENT and the reason.
    fn drop_worker(&mut self, id: u64, reason: &str, refuse: bool) {
        let Some(w) = self.workers.remove(&id) else {
            return;
        };
        let hosted = self
            .slots
            .iter()
            .filter(|s| s.home.is_some_and(|(h, _)| h == id))
            .count();
        tracing::warn!(
            "environment worker {} lost ({reason}); the episodes of its {hosted} environments \
             end truncated, and start again on the other workers",
            w.name
        );
        if refuse {
            let _ = w
                .commands
                .try_send(Err(Status::invalid_argument(reason.to_string())));
        }
    }

    /// The live worker and environment number of slot `i`, placing it on a worker first
    /// where it has none; None when stopped.
    fn home(&mut self, i: usize) -> Option<(u64, u32)> {
        if let Some((w, local)) = self.slots[i].home
            && self.workers.contains_key(&w)
        {
            return Some((w, local));
        }
        if !self.wait_for_workers() {
            return None;
        }
        let mut load: BTreeMap<u64, usize> = self.workers.keys().map(|&w| (w, 0)).collect();
        for s in &self.slots {
            if let Some((w, _)) = s.home
                && let Some(n) = load.get_mut(&w)
            {
                *n += 1;
            }
        }
        let spare = |w: &u64| self.workers[w].offered as usize > load[w];
        let chosen = load
            .iter()
            .filter(|(w, _)| spare(w))
            .map(|(w, _)| *w)
            .next()
            .or_else(|| load.iter().min_by_key(|(_, n)| **n).map(|(w, _)| *w))?;
        let worker = self.workers.get_mut(&chosen)?;
        let local = worker.hosted;
        worker.hosted += 1;
        self.slots[i].home = Some((chosen, local));
        Some((chosen, local))
    }

    fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    /// Sends each share to its worker and waits for every answer: the replies by worker
    /// (a worker gone, or that does not answer in time, is dropped and left out).
    fn exchange(&mut self, shares: &BTreeMap<u64, Share>) -> BTreeMap<u64, pb::EnvReply> {
        let mut waiting: BTreeMap<u64, u64> = BTreeMap::new();
        for (&w, share) in shares {
            let sent = self.workers.get(&w).map(|worker| {
                worker
                    .commands
                    .blocking_send(Ok(share.command.clone()))
                    .is_ok()
            });
            match sent {
                Some(true) => {
                    waiting.insert(w, share.command.seq);
                }
                Some(false) => self.drop_worker(w, "its command stream closed", false),
                None => {}
            }
        }
        let mut replies = BTreeMap::new();
        let deadline = Instant::now() + REPLY_TIMEOUT;
        while !waiting.is_empty() {
            let left = deadline.saturating_duration_since(Instant::now());
            match self
                .events
                .recv_timeout(left.min(Duration::from_millis(500)))
            {
                Ok((w, Event::Reply(r))) => match waiting.get(&w) {
                    Some(&seq) if r.seq == seq => {
                        waiting.remove(&w);
                        replies.insert(w, r);
                    }
                    _ => {
                        waiting.remove(&w);
                        self.drop_worker(w, "it answered a command not sent", true);
                    }
                },
                Ok((w, Event::Gone(reason))) => {
                    waiting.remove(&w);
                    self.drop_worker(w, &reason, false);
                }
                Err(mpsc::RecvTimeoutError::Timeout) if left.is_zero() => {
                    for (w, _) in std::mem::take(&mut waiting) {
                        let why = format!("no answer in {} s", REPLY_TIMEOUT.as_secs());
                        self.drop_worker(w, &why, true);
                    }
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
        }
        replies
    }

    /// Steps `slots` (each with its action): the step of each, lost where its worker is.
    fn step_slots(&mut self, slots: &[(usize, ActionRef<'_>)], out: &mut [Step]) {
        self.drain_events();
        let mut shares: BTreeMap<u64, Share> = BTreeMap::new();
        let seq = self.next_seq();
        for (j, &(i, action)) in slots.iter().enumerate() {
            let home = self.slots[i]
                .home
                .filter(|(w, _)| self.workers.contains_key(w));
            let Some((w, local)) = home else {
                out[j] = lost();
                continue;
            };
            let share = shares.entry(w).or_insert_with(|| Share {
                command: pb::EnvCommand {
                    seq,
                    envs: Vec::new(),
                    kind: Some(pb::env_command::Kind::Step(pb::StepCommand::default())),
                },
                slots: Vec::new(),
            });
            share.command.envs.push(local);
            share.slots.push(j);
            if let Some(pb::env_command::Kind::Step(step)) = share.command.kind.as_mut() {
                self.codec.encode_action(action, step);
            }
        }
        let mut replies = self.exchange(&shares);
        for (w, share) in &shares {
            let taken = replies
                .remove(w)
                .ok_or_else(|| "no answer".to_string())
                .and_then(|r| self.take_step_reply(&r, share, slots, out));
            if let Err(reason) = taken {
                if reason != "no answer" {
                    self.drop_worker(*w, &format!("a bad answer: {reason}"), true);
                }
                for &j in &share.slots {
                    out[j] = lost();
                }
            }
        }
    }

    /// Reads one worker's answer to a step into its slots and `out`.
    fn take_step_reply(
        &mut self,
        reply: &pb::EnvReply,
        share: &Share,
        slots: &[(usize, ActionRef<'_>)],
        out: &mut [Step],
    ) -> Result<(), String> {
        let rows = share.slots.len();
        let ended = check_step_reply(reply, rows, self.max_abs_reward)?;
        let mut reached = StateBatch::empty(&self.states);
        self.codec
            .decode_observations(reply.observations.as_ref(), rows, &mut reached)?;
        let mut starts = StateBatch::empty(&self.states);
        self.codec
            .decode_observations(reply.reset_observations.as_ref(), ended, &mut starts)
            .map_err(|e| format!("reset observations: {e}"))?;
        let mut next_start = 0;
        for (row, &j) in share.slots.iter().enumerate() {
            let (terminated, truncated) = (reply.terminated[row], reply.truncated[row]);
            out[j] = Step {
                reward: reply.rewards[row],
                terminated,
                truncated,
                success: false,
                lost: false,
            };
            let slot = &mut self.slots[slots[j].0];
            slot.state.clear();
            slot.state.push_row_of(&reached, row);
            slot.next_start = (terminated || truncated).then(|| {
                let mut s = StateBatch::empty(&self.states);
                s.push_row_of(&starts, next_start);
                next_start += 1;
                s
            });
        }
        Ok(())
    }
}

fn lost() -> Step {
    Step {
        lost: true,
        ..Step::default()
    }
}

/// One all-zero state of `space` (a slot's state before its first episode).
fn zero_state(space: &StateSpace) -> StateBatch {
    let mut s = StateBatch::empty(space);
    match &mut s {
        StateBatch::Categorical { factors, data } => data.resize(*factors, 0),
        StateBatch::Real { dim, data } => data.resize(*dim, 0.0),
    }
    s
}

impl EnvPool for RemotePool {
    fn len(&self) -> usize {
        self.slots.len() - 1
    }

    fn state_space(&self) -> &StateSpace {
        &self.states
    }

    fn action_space(&self) -> &ActionSpace {
        &self.actions
    }

    fn has_success(&self) -> bool {
        false
    }

    fn failure(&self) -> Option<String> {
        self.failure.clone()
    }

    /// Starts slot `i`'s next episode: the state its worker sent when the last one ended,
    /// or (the evaluation's slot, a slot that moved, the first episode) a reset with a seed
    /// drawn from `rng`.
    fn reset(&mut self, i: usize, rng: &mut ChaCha8Rng) {
        let seed: u64 = rng.random();
        let evaluation = i == self.len();
        let live = self.slots[i]
            .home
            .is_some_and(|(w, _)| self.workers.contains_key(&w));
        if let Some(start) = self.slots[i].next_start.take()
            && live
            && !evaluation
        {
            self.slots[i].state = start;
            return;
        }
        loop {
            let Some((w, local)) = self.home(i) else {
                return;
            };
            let seq = self.next_seq();
            let share = Share {
                command: pb::EnvCommand {
                    seq,
                    envs: vec![local],
                    kind: Some(pb::env_command::Kind::Reset(pb::ResetCommand {
                        seeds: vec![seed],
                    })),
                },
                slots: vec![i],
            };
            let mut replies = self.exchange(&BTreeMap::from([(w, share)]));
            let Some(reply) = replies.remove(&w) else {
                continue;
            };
            let mut state = StateBatch::empty(&self.states);
            match self
                .codec
                .decode_observations(reply.observations.as_ref(), 1, &mut state)
            {
                Ok(()) => {
                    self.slots[i].state = state;
                    return;
                }
                Err(reason) => self.drop_worker(w, &format!("a bad reset: {reason}"), true),
            }
        }
    }

    fn step(&mut self, actions: &ActionBatch, out: &mut [Step]) {
        let slots: Vec<(usize, ActionRef<'_>)> = (0..out.len())
            .map(|i| (i, ActionRef::row(actions, i)))
            .collect();
        self.step_slots(&slots, out);
    }

    fn step_one(&mut self, i: usize, action: ActionRef<'_>) -> Step {
        let mut out = [Step::default()];
        self.step_slots(&[(i, action)], &mut out);
        out[0]
    }

    fn push_state(&self, i: usize, out: &mut StateBatch) {
        out.push_row_of(&self.slots[i].state, 0);
    }
}

impl Drop for RemotePool {
    fn drop(&mut self) {
        if !self.workers.is_empty() {
            tracing::debug!(
                "closing the streams of {} environment workers",
                self.workers.len()
            );
        }
    }
}
