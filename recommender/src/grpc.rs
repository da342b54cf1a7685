//! The gRPC face of a [`Recommender`]: the `jsae.v1.Recommender` handlers (Recommend, and
//! SubmitSessions, whose work is `crate::submit`) and `serve`, which runs them beside health
//! and reflection and follows the weight sources.

use std::sync::Arc;

use jsae_net as net;
use jsae_net::security::Security;
use jsae_wire::{MAX_MESSAGE_BYTES, pb};
use tokio::net::TcpListener;
use tonic::{Request, Response, Status, Streaming};

use jsae_telemetry::RecommenderMetrics;

use crate::scoring::Recommender;
use crate::sources::{WeightSources, follow};
use crate::submit::{MAX_REQUEST_BYTES, SubmitBudget, receive_sessions};

/// The gRPC face of a [`Recommender`].
#[derive(Debug, Clone)]
pub struct RecommenderService {
    inner: Arc<Recommender>,
    metrics: RecommenderMetrics,
    submits: SubmitBudget,
}

impl RecommenderService {
    /// Serves `inner`, counting into `metrics`.
    pub fn new(inner: Arc<Recommender>, metrics: RecommenderMetrics) -> Self {
        Self {
            inner,
            metrics,
            submits: SubmitBudget::default(),
        }
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
        let answered = receive_sessions(&self.inner, &self.submits, request)
            .await
            .map(Response::new);
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
        .max_decoding_message_size(MAX_REQUEST_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES);
    let result = net::serve(server, listener, &security, None, shutdown).await;
    tasks.abort_all();
    result?;
    Ok(())
}
