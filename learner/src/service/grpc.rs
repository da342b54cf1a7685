//! The `jsae.v1.Learner` handlers: `PushFragments` checks each fragment (size, dimensions,
//! at least one step, every value within what an actor can send: `FragmentBounds`), a
//! policy version this learner has published, an embedding version its embedder has
//! published) and queues it for the training thread; `WatchPolicy` streams snapshots, the
//! evaluation request (to the asked actor's stream only), each actor's share of a shared
//! batch (to its own stream) and the end of the run, and tells the training thread which
//! actors' streams are open; `ReportEval` takes the asked actor's evaluation.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use jsae_net as net;
use jsae_net::streams::StreamLimit;
use jsae_wire::{self as wire, pb};
use jsae_wire::{EvalReport, FragmentBounds, PolicySnapshot, RolloutFragment, RpcError};
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use super::evaluation::{ActorIds, OpenStream};
use super::input::{Announced, Input};

/// Largest fragment accepted, in steps.
pub const MAX_FRAGMENT_STEPS: usize = 65_536;

/// How long a fragment of an embedding version the learner has not seen yet waits for the
/// embedder's stream to bring it (an actor may hear of a new version a moment before the
/// learner does), before it is refused as unknown.
pub const EMBEDDING_GRACE: Duration = Duration::from_secs(2);

/// How long a new actor's stream waits for its share of a shared batch before the first
/// snapshot goes out (else its first rollout steps all of its environments).
pub const SHARE_GRACE: Duration = Duration::from_secs(2);

/// What the policy stream carries: the current snapshot, an evaluation request, each
/// actor's share of a shared batch, the end.
#[derive(Debug, Clone, Default)]
pub(super) struct PolicyState {
    pub(super) snapshot: Option<Arc<PolicySnapshot>>,
    /// The open evaluation request; only the stream of the actor it names carries it.
    pub(super) evaluate: Option<pb::EvalRequest>,
    /// The environments each present actor steps (empty unless the batch is shared); only
    /// the stream of the actor named carries its share.
    pub(super) shares: BTreeMap<u64, u32>,
    pub(super) finished: bool,
}

/// The `jsae.v1.Learner` implementation.
#[derive(Debug, Clone)]
pub struct LearnerService {
    /// What a fragment may carry (`Learner::fragment_bounds`).
    pub(super) bounds: FragmentBounds,
    pub(super) version: Arc<AtomicU64>,
    /// The highest embedding version the embedder has published to this learner (None: a
    /// run without an embedder, whose fragments carry version 0).
    pub(super) embedding: Option<watch::Receiver<u64>>,
    pub(super) queue: mpsc::Sender<Input>,
    pub(super) state: watch::Receiver<PolicyState>,
    pub(super) stopping: watch::Receiver<bool>,
    /// Whether the batch is shared among the actors (`batch_envs`): a new actor's stream
    /// then waits up to [`SHARE_GRACE`] for its share.
    pub(super) shares_batch: bool,
    /// The open policy streams, capped in all and per connection.
    pub(super) watches: StreamLimit,
    /// Which connection holds each actor id.
    pub(super) actor_ids: ActorIds,
}

impl LearnerService {
    /// The fragment, or why it is refused (logged).
    async fn check(
        &self,
        index: u64,
        msg: pb::RolloutFragment,
    ) -> Result<RolloutFragment, RpcError> {
        let actor = msg.actor_id;
        let checked = self.checked(index, msg).await;
        if let Err(e) = &checked {
            tracing::warn!("learner: a fragment of actor {actor} refused: {e}");
        }
        checked
    }

    async fn checked(
        &self,
        index: u64,
        msg: pb::RolloutFragment,
    ) -> Result<RolloutFragment, RpcError> {
        if msg.rewards.len() > MAX_FRAGMENT_STEPS {
            return Err(RpcError::ResourceExhausted(format!(
                "fragment {index}: {} steps, at most {MAX_FRAGMENT_STEPS}",
                msg.rewards.len()
            )));
        }
        let bad = |e: String| RpcError::InvalidArgument(format!("fragment {index}: {e}"));
        let fragment = RolloutFragment::try_from(msg).map_err(|e| bad(e.to_string()))?;
        fragment
            .validate(&self.bounds)
            .map_err(|e| bad(e.to_string()))?;
        let current = self.version.load(Ordering::Acquire);
        if fragment.policy_version > current {
            return Err(bad(format!(
                "unknown policy version {} (this learner is at {current})",
                fragment.policy_version
            )));
        }
        let embedding = fragment.embedding_version;
        if let Err(published) = self.embedding_published(embedding).await {
            return Err(bad(format!(
                "unknown embedding version {embedding} (the embedder has published up to \
                 {published})"
            )));
        }
        Ok(fragment)
    }

    /// Why an evaluation report answering `asked` cannot be true: episode counts, lengths
    /// or returns the environment cannot give ([`EvalReport::check`]), a policy version this
    /// learner has not published, an embedding version other than the one asked for (or,
    /// without one named, one the embedder has not published).
    fn implausible(&self, report: &EvalReport, asked: &pb::EvalRequest) -> Result<(), String> {
        report
            .check(asked.episodes, &self.bounds)
            .map_err(|e| e.to_string())?;
        let current = self.version.load(Ordering::Acquire);
        if report.policy_version > current {
            return Err(format!(
                "policy version {} (this learner is at {current})",
                report.policy_version
            ));
        }
        let published = self.embedding.as_ref().map_or(0, |p| *p.borrow());
        let embedding = report.embedding_version;
        let known = match asked.embedding_version {
            0 => embedding <= published,
            wanted => embedding == wanted,
        };
        if !known {
            return Err(format!(
                "embedding version {embedding} (asked for {}, the embedder has published up \
                 to {published})",
                asked.embedding_version
            ));
        }
        Ok(())
    }

    /// Whether the embedder has published `version` (0, no embedding, always counts), waiting
    /// at most [`EMBEDDING_GRACE`] for it to arrive; the highest version published otherwise.
    async fn embedding_published(&self, version: u64) -> Result<(), u64> {
        let Some(published) = &self.embedding else {
            return if version == 0 { Ok(()) } else { Err(0) };
        };
        let mut published = published.clone();
        let arrived = tokio::time::timeout(
            EMBEDDING_GRACE,
            published.wait_for(|&newest| newest >= version),
        )
        .await
        .is_ok_and(|seen| seen.is_ok());
        if arrived {
            Ok(())
        } else {
            Err(*published.borrow())
        }
    }
}

#[tonic::async_trait]
impl pb::learner_server::Learner for LearnerService {
    async fn push_fragments(
        &self,
        request: Request<Streaming<pb::RolloutFragment>>,
    ) -> Result<Response<pb::PushSummary>, Status> {
        let accepted = net::receive_all(
            request.into_inner(),
            &self.stopping,
            "learner",
            |i, msg| async move {
                let checked = self.check(i, msg).await?;
                self.queue
                    .send(Input::Fragment(Box::new(checked)))
                    .await
                    .map_err(|_| RpcError::shutting_down("learner").into())
            },
        )
        .await?;
        Ok(Response::new(pb::PushSummary {
            accepted,
            rejected: 0,
        }))
    }

    type WatchPolicyStream = ReceiverStream<Result<pb::PolicyEvent, Status>>;

    async fn watch_policy(
        &self,
        request: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchPolicyStream>, Status> {
        use pb::policy_event::Event;
        let peer = request.remote_addr();
        let permit = self.watches.enter(peer)?;
        let watch = request.into_inner();
        let claim = if watch.evaluates {
            Some(self.actor_ids.claim(watch.actor_id, peer)?)
        } else {
            None
        };
        // an actor's stream is counted while it is open: the batch is its share of a shared
        // batch, or one rollout of it (`roster`), and an actor that dies while asked for the
        // evaluation is replaced
        // (none when the training thread is gone: the run is over, and the stream still
        // brings the last snapshot and the end)
        let actor = if watch.evaluates {
            let announced = Announced {
                rollout_steps: watch.rollout_steps,
                envs: watch.envs,
            };
            OpenStream::announce(watch.actor_id, announced, &self.queue).await
        } else {
            None
        };
        if self.shares_batch && watch.envs > 0 && actor.is_some() {
            let (mut state, mut stopping) = (self.state.clone(), self.stopping.clone());
            let told = |s: &PolicyState| s.finished || s.shares.contains_key(&watch.actor_id);
            tokio::select! {
                _ = tokio::time::timeout(SHARE_GRACE, state.wait_for(told)) => {}
                _ = stopping.wait_for(|&stop| stop) => {}
            }
        }
        let (mut sent_version, mut sent_eval, mut sent_share) = (None, None, None);
        let stream = net::watch_stream(self.state.clone(), &self.stopping, permit, move |now| {
            let _held = &claim;
            let mut events = Vec::new();
            // the share first: it applies to the rollouts under the snapshot that follows. A
            // stream opens with one (0, all: the batch is not shared, or not yet known), so an
            // actor told a share by an earlier learner does not keep it; an absent actor is
            // left its last.
            if let Some(a) = &actor {
                let envs = match (now.shares.get(&a.actor()), sent_share) {
                    (Some(&envs), _) => Some(envs),
                    (None, None) => Some(0),
                    (None, Some(_)) => None,
                };
                if let Some(envs) = envs
                    && sent_share != Some(envs)
                {
                    sent_share = Some(envs);
                    events.push(Event::Share(pb::Share { envs }));
                }
            }
            // the snapshot's chunks are cut as they are sent, from the one shared snapshot
            let mut chunks = None;
            if let Some(s) = &now.snapshot
                && sent_version != Some(s.version)
            {
                sent_version = Some(s.version);
                chunks = Some(wire::policy_chunks(s.clone()).map(Event::Chunk));
            }
            let mut after = Vec::new();
            if let Some(e) = &now.evaluate
                && actor.as_ref().is_some_and(|a| a.actor() == e.actor_id)
                && sent_eval != Some(e.request_id)
            {
                sent_eval = Some(e.request_id);
                after.push(Event::Evaluate(*e));
            }
            if now.finished {
                after.push(Event::Finish(pb::Finish {}));
            }
            let events = events
                .into_iter()
                .chain(chunks.into_iter().flatten())
                .chain(after)
                .map(|event| pb::PolicyEvent { event: Some(event) });
            (events, now.finished)
        });
        Ok(Response::new(stream))
    }

    async fn report_eval(
        &self,
        request: Request<pb::EvalReport>,
    ) -> Result<Response<pb::Ack>, Status> {
        let msg = request.into_inner();
        let actor = msg.actor_id;
        let (report, id) = EvalReport::from_wire(msg)
            .map_err(|e| RpcError::InvalidArgument(format!("eval report: {e}")))?;
        let open = self.state.borrow().evaluate;
        let refused = match open {
            Some(asked) if asked.request_id == id && asked.actor_id == actor => None,
            Some(asked) if asked.request_id == id => Some(RpcError::PermissionDenied(format!(
                "evaluation request {id} asked actor {}, not actor {actor}",
                asked.actor_id
            ))),
            _ => Some(RpcError::FailedPrecondition(format!(
                "no evaluation request {id} is open"
            ))),
        };
        let refused = refused.or_else(|| {
            let asked = open?;
            self.implausible(&report, &asked)
                .err()
                .map(|e| RpcError::InvalidArgument(format!("eval report: {e}")))
        });
        if let Some(e) = refused {
            tracing::warn!("learner: an evaluation report of actor {actor} refused: {e}");
            return Err(e.into());
        }
        self.queue
            .send(Input::Eval(report, id))
            .await
            .map_err(|_| RpcError::shutting_down("learner"))?;
        Ok(Response::new(pb::Ack {}))
    }
}
