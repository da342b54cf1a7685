//! Reading a recording back: its transitions (for pre-training) and a summary
//! (`jsae record-info`). A file cut short by a crash reads up to its last whole chunk.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace, TransitionBatch};
use prost::Message;
use serde::Serialize;

use crate::{RecordError, RecordingInfo, SCHEMA_NAME, pb};

/// The transitions of a recording, in the order they were written.
#[derive(Debug, Clone)]
pub struct Recording {
    /// What the channel says about the run.
    pub info: RecordingInfo,
    /// The transitions.
    pub transitions: Vec<pb::Transition>,
    /// Why reading stopped before the file's end (a crash cut the file), if it did.
    pub cut_short: Option<String>,
    /// Whether the file ends with its summary and footer (the recorder finished).
    pub finished: bool,
}

/// Reads every transition of `path`, or the first `limit`.
pub fn read(path: &Path, limit: Option<usize>) -> Result<Recording, RecordError> {
    let bytes = std::fs::read(path).map_err(RecordError::io(path))?;
    let finished = mcap::read::footer(&bytes).is_ok();
    let stream = mcap::MessageStream::new(&bytes).map_err(RecordError::mcap(path))?;
    let mut info: Option<RecordingInfo> = None;
    let mut transitions = Vec::new();
    let mut cut_short = None;
    for message in stream {
        if limit.is_some_and(|n| transitions.len() >= n) {
            break;
        }
        let message = match message {
            Ok(m) => m,
            Err(e) if !transitions.is_empty() => {
                cut_short = Some(e.to_string());
                break;
            }
            Err(e) => return Err(RecordError::mcap(path)(e)),
        };
        let channel = &message.channel;
        if channel
            .schema
            .as_ref()
            .is_none_or(|s| s.name != SCHEMA_NAME)
        {
            continue;
        }
        let this = RecordingInfo::from_metadata(&channel.metadata)
            .map_err(|reason| RecordError::format(path, reason))?;
        match &info {
            None => info = Some(this),
            Some(first) if first.states != this.states || first.actions != this.actions => {
                return Err(RecordError::format(
                    path,
                    "its channels record different state or action spaces",
                ));
            }
            Some(_) => {}
        }
        let t = pb::Transition::decode(message.data.as_ref())
            .map_err(|e| RecordError::format(path, format!("message {}: {e}", message.sequence)))?;
        transitions.push(t);
    }
    let info = info.ok_or_else(|| {
        RecordError::format(path, format!("no {SCHEMA_NAME} message in the file"))
    })?;
    Ok(Recording {
        info,
        transitions,
        cut_short,
        finished,
    })
}

fn push_state(
    batch: &mut StateBatch,
    space: &StateSpace,
    real: &[f32],
    categories: &[u32],
) -> Result<(), String> {
    match (batch, space) {
        (StateBatch::Real { dim, data }, _) if real.len() == *dim && categories.is_empty() => {
            data.extend_from_slice(real);
        }
        (StateBatch::Categorical { factors, data }, StateSpace::Categorical { sizes })
            if categories.len() == *factors && real.is_empty() =>
        {
            if let Some((c, n)) = categories
                .iter()
                .zip(sizes)
                .find(|(c, n)| **c as usize >= **n)
            {
                return Err(format!("category {c} of a factor with {n}"));
            }
            data.extend_from_slice(categories);
        }
        _ => {
            return Err(format!(
                "a state of {} real and {} categorical values",
                real.len(),
                categories.len()
            ));
        }
    }
    Ok(())
}

impl Recording {
    /// The transitions as one batch for the embedder (checked against the recording's
    /// spaces: a malformed message is refused with its position).
    pub fn transition_batch(&self, path: &Path) -> Result<TransitionBatch, RecordError> {
        let (states, actions) = (&self.info.states, &self.info.actions);
        let mut batch = TransitionBatch {
            actor_id: 0,
            states: StateBatch::empty(states),
            actions: ActionBatch::empty(actions),
            rewards: Vec::with_capacity(self.transitions.len()),
            next_states: StateBatch::empty(states),
            terminated: Vec::with_capacity(self.transitions.len()),
        };
        for (k, t) in self.transitions.iter().enumerate() {
            let bad =
                |reason: String| RecordError::format(path, format!("transition {k}: {reason}"));
            push_state(&mut batch.states, states, &t.state, &t.state_categories).map_err(bad)?;
            push_state(
                &mut batch.next_states,
                states,
                &t.next_state,
                &t.next_state_categories,
            )
            .map_err(bad)?;
            match (&mut batch.actions, actions, t.discrete_action) {
                (ActionBatch::Discrete(v), ActionSpace::Discrete { n }, Some(a))
                    if (a as usize) < *n =>
                {
                    v.push(a);
                }
                (ActionBatch::Continuous { dim, data }, _, None)
                    if t.continuous_action.len() == *dim =>
                {
                    data.extend_from_slice(&t.continuous_action);
                }
                _ => return Err(bad("an action outside the action space".into())),
            }
            batch.rewards.push(t.reward);
            batch.terminated.push(t.terminated);
        }
        Ok(batch)
    }
}

/// What `jsae record-info` prints about a recording.
#[derive(Debug, Clone, Serialize)]
pub struct RecordSummary {
    /// The file.
    pub file: PathBuf,
    /// Its size.
    pub bytes: u64,
    /// Whether it ends with its summary and footer (the recorder finished).
    pub finished: bool,
    /// Why reading stopped early (a crash cut the file), if it did.
    pub cut_short: Option<String>,
    /// What the channel says about the run.
    pub run: RecordingInfo,
    /// Transitions in the file.
    pub transitions: u64,
    /// Transitions per actor id.
    pub per_actor: BTreeMap<u64, u64>,
    /// Distinct (actor, environment) pairs.
    pub environments: usize,
    /// Episodes that ended in the file: terminated and truncated.
    pub episodes_ended: u64,
    /// Of those, terminated.
    pub terminated: u64,
    /// Of those, truncated.
    pub truncated: u64,
    /// Mean return of the episodes that started and ended in the file.
    pub episode_return_mean: Option<f64>,
    /// Transitions of random play (policy version 0).
    pub random_play: u64,
    /// The lowest and the highest policy version that acted.
    pub policy_versions: Option<(u64, u64)>,
    /// The lowest and the highest embedding version that acted.
    pub embedding_versions: Option<(u64, u64)>,
    /// Mean reward per transition.
    pub reward_mean: Option<f64>,
}

/// Reads `path` and summarises it.
pub fn summarize(path: &Path) -> Result<RecordSummary, RecordError> {
    let bytes = std::fs::metadata(path)
        .map_err(RecordError::io(path))?
        .len();
    let rec = read(path, None)?;
    let mut per_actor = BTreeMap::new();
    let mut envs = BTreeSet::new();
    // running return of each (actor, env, episode) seen from its first step
    let mut open: BTreeMap<(u64, u32), (u64, f64)> = BTreeMap::new();
    let (mut returns, mut terminated, mut truncated, mut random, mut reward) =
        (Vec::new(), 0u64, 0u64, 0u64, 0.0f64);
    let span = |acc: Option<(u64, u64)>, v: u64| {
        Some(acc.map_or((v, v), |(lo, hi): (u64, u64)| (lo.min(v), hi.max(v))))
    };
    let (mut pv, mut ev) = (None, None);
    for t in &rec.transitions {
        *per_actor.entry(t.actor_id).or_insert(0u64) += 1;
        let key = (t.actor_id, t.env_index);
        envs.insert(key);
        reward += f64::from(t.reward);
        if t.policy_version == 0 {
            random += 1;
        } else {
            pv = span(pv, t.policy_version);
        }
        if t.embedding_version > 0 {
            ev = span(ev, t.embedding_version);
        }
        if t.step == 0 {
            open.insert(key, (t.episode, 0.0));
        }
        if let Some((episode, ret)) = open.get_mut(&key)
            && *episode == t.episode
        {
            *ret += f64::from(t.reward);
        }
        if t.terminated || t.truncated {
            terminated += u64::from(t.terminated);
            truncated += u64::from(!t.terminated);
            if let Some((episode, ret)) = open.remove(&key)
                && episode == t.episode
            {
                returns.push(ret);
            }
        }
    }
    let n = rec.transitions.len() as u64;
    let mean = |sum: f64, count: usize| (count > 0).then(|| sum / count as f64);
    Ok(RecordSummary {
        file: path.to_path_buf(),
        bytes,
        finished: rec.finished,
        cut_short: rec.cut_short,
        run: rec.info,
        transitions: n,
        per_actor,
        environments: envs.len(),
        episodes_ended: terminated + truncated,
        terminated,
        truncated,
        episode_return_mean: mean(returns.iter().sum(), returns.len()),
        random_play: random,
        policy_versions: pv,
        embedding_versions: ev,
        reward_mean: mean(reward, n as usize),
    })
}
