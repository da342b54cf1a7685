//! The gRPC face of a [`Recommender`]: the `jsae.v1.Recommender` handlers (Recommend,
//! SubmitSessions with its limits and error list) and `serve`, which runs them beside health
//! and reflection and follows the weight sources.

use std::sync::Arc;

use jsae_envs::recsys::sessions::{Session, check_session};
use jsae_proto::net;
use jsae_proto::security::Security;
use jsae_proto::wire::{MAX_MESSAGE_BYTES, pb};
use tokio::net::TcpListener;
use tonic::{Request, Response, Status, Streaming};

use jsae_proto::RpcError;
use jsae_telemetry::RecommenderMetrics;

use crate::scoring::{MAX_ERRORS_LISTED, MAX_SESSIONS_PER_CALL, Recommender};
use crate::sources::{WeightSources, follow};

/// Accepted sessions are written to the store in groups of this many (and at the end).
const STORE_BATCH: usize = 1024;
/// The gRPC face of a [`Recommender`].
#[derive(Debug, Clone)]
pub struct RecommenderService {
    inner: Arc<Recommender>,
    metrics: RecommenderMetrics,
}

impl RecommenderService {
    /// Serves `inner`, counting into `metrics`.
    pub fn new(inner: Arc<Recommender>, metrics: RecommenderMetrics) -> Self {
        Self { inner, metrics }
    }
}

/// A status code as a metrics label.
fn code_label(code: tonic::Code) -> &'static str {
    use tonic::Code;
    match code {
        Code::Ok => "ok",
        Code::InvalidArgument => "invalid_argument",
        Code::ResourceExhausted => "resource_exhausted",
        Code::Unavailable => "unavailable",
        Code::Cancelled => "cancelled",
        Code::Internal => "internal",
        _ => "other",
    }
}

/// Writes `pending` to the store off the async threads (the sync waits for the disk).
async fn flush(inner: &Arc<Recommender>, pending: &mut Vec<Session>) -> Result<(), RpcError> {
    if pending.is_empty() {
        return Ok(());
    }
    let inner = inner.clone();
    let batch = std::mem::take(pending);
    tokio::task::spawn_blocking(move || inner.store(&batch))
        .await
        .map_err(|e| RpcError::Internal(e.to_string()))?
}

#[tonic::async_trait]
impl pb::recommender_server::Recommender for RecommenderService {
    async fn recommend(
        &self,
        request: Request<pb::RecommendRequest>,
    ) -> Result<Response<pb::RecommendResponse>, Status> {
        let started = std::time::Instant::now();
        let r = request.into_inner();
        let answered = self.inner.recommend(&r.history, r.k);
        let seconds = started.elapsed().as_secs_f64();
        let out = match answered {
            Ok(out) => {
                self.metrics
                    .observe_recommend(seconds, "ok", Some(out.policy_version));
                out
            }
            Err(e) => {
                let status = Status::from(e);
                self.metrics
                    .observe_recommend(seconds, code_label(status.code()), None);
                return Err(status);
            }
        };
        Ok(Response::new(pb::RecommendResponse {
            items: out
                .items
                .into_iter()
                .map(|(item_id, score)| pb::ScoredItem { item_id, score })
                .collect(),
            policy_version: out.policy_version,
            embedding_version: out.embedding_version,
            unknown_items: out.unknown_items,
        }))
    }

    async fn submit_sessions(
        &self,
        request: Request<Streaming<pb::Session>>,
    ) -> Result<Response<pb::SubmitSummary>, Status> {
        let answered = self.receive_sessions(request).await;
        let (code, accepted, rejected) = match &answered {
            Ok(summary) => (
                "ok",
                summary.get_ref().sessions_accepted,
                summary.get_ref().sessions_rejected,
            ),
            Err(status) => (code_label(status.code()), 0, 0),
        };
        self.metrics.observe_submit(code, accepted, rejected);
        answered
    }
}

impl RecommenderService {
    /// SubmitSessions itself (the trait method counts its outcome).
    async fn receive_sessions(
        &self,
        request: Request<Streaming<pb::Session>>,
    ) -> Result<Response<pb::SubmitSummary>, Status> {
        let mut stream = request.into_inner();
        let mut summary = pb::SubmitSummary::default();
        let mut pending: Vec<Session> = Vec::new();
        let mut index: u64 = 0;
        loop {
            let message = match stream.message().await {
                Ok(Some(m)) => m,
                Ok(None) => break,
                Err(status) => {
                    // keep what was accepted before the stream broke (or a message was over
                    // the size limit: RESOURCE_EXHAUSTED)
                    flush(&self.inner, &mut pending).await?;
                    return Err(jsae_proto::wire::receive_error(status));
                }
            };
            if index >= MAX_SESSIONS_PER_CALL {
                flush(&self.inner, &mut pending).await?;
                return Err(RpcError::ResourceExhausted(format!(
                    "more than {MAX_SESSIONS_PER_CALL} sessions in one call: the first \
                     {MAX_SESSIONS_PER_CALL} were processed ({} accepted); send the rest in \
                     another call",
                    summary.sessions_accepted
                ))
                .into());
            }
            let session = Session::from(message);
            match check_session(&session) {
                Ok(()) => {
                    summary.sessions_accepted += 1;
                    summary.purchases_accepted += session.purchases.len() as u64;
                    pending.push(session);
                    if pending.len() >= STORE_BATCH {
                        flush(&self.inner, &mut pending).await?;
                    }
                }
                Err(reason) => {
                    summary.sessions_rejected += 1;
                    if summary.errors.len() < MAX_ERRORS_LISTED {
                        let id: String = session.session_id.chars().take(64).collect();
                        summary.errors.push(format!(
                            "session {index} (session_id {id:?}): INVALID_ARGUMENT: {reason}"
                        ));
                    }
                }
            }
            index += 1;
        }
        if index == 0 {
            return Err(
                RpcError::InvalidArgument("no sessions: the stream was empty".into()).into(),
            );
        }
        flush(&self.inner, &mut pending).await?;
        if summary.sessions_rejected > summary.errors.len() as u64 {
            let more = summary.sessions_rejected - summary.errors.len() as u64;
            summary
                .errors
                .push(format!("... and {more} more rejected sessions"));
        }
        Ok(Response::new(summary))
    }
}

/// Serves `rec` on `listener` until `shutdown` resolves, following the weight sources;
/// `security` is required of callers and used towards the sources.
pub async fn serve(
    rec: Arc<Recommender>,
    listener: TcpListener,
    sources: WeightSources,
    metrics: RecommenderMetrics,
    security: Security,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let mut tasks = follow(&rec, &sources, &security);
    let service = RecommenderService::new(rec, metrics);
    let server = pb::recommender_server::RecommenderServer::new(service)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);
    let result = net::serve(server, listener, &security, shutdown).await;
    tasks.abort_all();
    result?;
    Ok(())
}
