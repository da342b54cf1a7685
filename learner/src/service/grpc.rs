//! The `jsae.v1.Learner` handlers: `PushFragments` checks each fragment (size, dimensions,
//! finite values, a policy version this learner has published) and queues it for the training
//! thread; `WatchPolicy` streams snapshots, the evaluation request and the end of the run;
//! `ReportEval` takes the actors' evaluation.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use jsae_proto::wire::{self, pb};
use jsae_proto::{
    ActionSpace, EmbeddingSnapshot, EvalReport, PolicySnapshot, RolloutFragment, RpcError, net,
};
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

/// Largest fragment accepted, in steps.
pub const MAX_FRAGMENT_STEPS: usize = 65_536;

/// What the learner thread is told.
#[derive(Debug)]
pub(super) enum Input {
    /// A checked fragment.
    Fragment(Box<RolloutFragment>),
    /// A new embedding version (JSAE).
    Embedding(EmbeddingSnapshot),
    /// An evaluation report and the request it answers.
    Eval(EvalReport, u64),
}

/// What the policy stream carries: the current snapshot, an evaluation request, the end.
#[derive(Debug, Clone, Default)]
pub(super) struct PolicyState {
    pub(super) snapshot: Option<Arc<PolicySnapshot>>,
    pub(super) evaluate: Option<pb::EvalRequest>,
    pub(super) finished: bool,
}

/// The `jsae.v1.Learner` implementation.
#[derive(Debug, Clone)]
pub struct LearnerService {
    pub(super) x_dim: usize,
    pub(super) actions: ActionSpace,
    pub(super) version: Arc<AtomicU64>,
    pub(super) queue: mpsc::Sender<Input>,
    pub(super) state: watch::Receiver<PolicyState>,
    pub(super) stopping: watch::Receiver<bool>,
}

impl LearnerService {
    fn check(&self, index: u64, msg: pb::RolloutFragment) -> Result<RolloutFragment, RpcError> {
        if msg.rewards.len() > MAX_FRAGMENT_STEPS {
            return Err(RpcError::ResourceExhausted(format!(
                "fragment {index}: {} steps, at most {MAX_FRAGMENT_STEPS}",
                msg.rewards.len()
            )));
        }
        let bad = |e: String| RpcError::InvalidArgument(format!("fragment {index}: {e}"));
        let fragment = RolloutFragment::try_from(msg).map_err(|e| bad(e.to_string()))?;
        fragment
            .validate(self.x_dim, &self.actions)
            .map_err(|e| bad(e.to_string()))?;
        let current = self.version.load(Ordering::Acquire);
        if fragment.policy_version > current {
            return Err(bad(format!(
                "unknown policy version {} (this learner is at {current})",
                fragment.policy_version
            )));
        }
        Ok(fragment)
    }
}

#[tonic::async_trait]
impl pb::learner_server::Learner for LearnerService {
    async fn push_fragments(
        &self,
        request: Request<Streaming<pb::RolloutFragment>>,
    ) -> Result<Response<pb::PushSummary>, Status> {
        let accepted =
            net::receive_all(request.into_inner(), &self.stopping, "learner", |i, msg| {
                let checked = self.check(i, msg);
                async move {
                    self.queue
                        .send(Input::Fragment(Box::new(checked?)))
                        .await
                        .map_err(|_| RpcError::shutting_down("learner").into())
                }
            })
            .await?;
        Ok(Response::new(pb::PushSummary {
            accepted,
            rejected: 0,
        }))
    }

    type WatchPolicyStream = ReceiverStream<Result<pb::PolicyEvent, Status>>;

    async fn watch_policy(
        &self,
        _request: Request<pb::WatchRequest>,
    ) -> Result<Response<Self::WatchPolicyStream>, Status> {
        use pb::policy_event::Event;
        let (mut sent_version, mut sent_eval) = (None, None);
        let stream = net::watch_stream(self.state.clone(), &self.stopping, move |now| {
            let mut events = Vec::new();
            if let Some(s) = &now.snapshot
                && sent_version != Some(s.version)
            {
                sent_version = Some(s.version);
                events.extend(wire::policy_chunks(s).into_iter().map(Event::Chunk));
            }
            if let Some(e) = &now.evaluate
                && sent_eval != Some(e.request_id)
            {
                sent_eval = Some(e.request_id);
                events.push(Event::Evaluate(*e));
            }
            if now.finished {
                events.push(Event::Finish(pb::Finish {}));
            }
            let events = events
                .into_iter()
                .map(|event| pb::PolicyEvent { event: Some(event) });
            (events.collect(), now.finished)
        });
        Ok(Response::new(stream))
    }

    async fn report_eval(
        &self,
        request: Request<pb::EvalReport>,
    ) -> Result<Response<pb::Ack>, Status> {
        let (report, id) = EvalReport::from_wire(request.into_inner())
            .map_err(|e| RpcError::InvalidArgument(format!("eval report: {e}")))?;
        let asked = self.state.borrow().evaluate.map(|e| e.request_id);
        if asked != Some(id) {
            return Err(RpcError::FailedPrecondition(format!(
                "no evaluation request {id} is open"
            ))
            .into());
        }
        self.queue
            .send(Input::Eval(report, id))
            .await
            .map_err(|_| RpcError::shutting_down("learner"))?;
        Ok(Response::new(pb::Ack {}))
    }
}
