//! `grpc.health.v1.Health` for every service, without the token: `Check` answers SERVING for
//! the whole server ("") and for the service it serves, NOT_FOUND for any other name; `Watch`
//! sends the same status once and stays open until the client leaves or the server stops,
//! at most [`MAX_HEALTH_WATCHES`] at once and [`MAX_HEALTH_WATCHES_PER_CONNECTION`] on one
//! connection (tonic-health's own reporter holds any number of them open).

use tonic::{Request, Response, Status};
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::health_server::{Health, HealthServer};
use tonic_health::pb::{HealthCheckRequest, HealthCheckResponse};

use crate::streams::{Cap, MAX_HEALTH_WATCHES, MAX_HEALTH_WATCHES_PER_CONNECTION, StreamLimit};

/// The health of a server that serves `service` until `stopping` turns true.
#[derive(Debug, Clone)]
pub struct ServingHealth {
    service: &'static str,
    stopping: tokio::sync::watch::Receiver<bool>,
    watches: StreamLimit,
}

impl ServingHealth {
    /// Health for the service named `service` (its `NamedService::NAME`).
    pub fn new(
        service: &'static str,
        stopping: tokio::sync::watch::Receiver<bool>,
    ) -> HealthServer<Self> {
        HealthServer::new(Self {
            service,
            stopping,
            watches: StreamLimit::new(
                "Health.Watch",
                Cap {
                    n: MAX_HEALTH_WATCHES,
                    name: "MAX_HEALTH_WATCHES",
                },
                Cap {
                    n: MAX_HEALTH_WATCHES_PER_CONNECTION,
                    name: "MAX_HEALTH_WATCHES_PER_CONNECTION",
                },
            ),
        })
    }

    fn status(&self, asked: &str) -> Result<HealthCheckResponse, Status> {
        if asked.is_empty() || asked == self.service {
            Ok(HealthCheckResponse {
                status: ServingStatus::Serving.into(),
            })
        } else {
            Err(Status::not_found(format!(
                "no service {asked} here (this server serves {})",
                self.service
            )))
        }
    }
}

#[tonic::async_trait]
impl Health for ServingHealth {
    async fn check(
        &self,
        request: Request<HealthCheckRequest>,
    ) -> Result<Response<HealthCheckResponse>, Status> {
        self.status(&request.get_ref().service).map(Response::new)
    }

    type WatchStream = tokio_stream::wrappers::ReceiverStream<Result<HealthCheckResponse, Status>>;

    async fn watch(
        &self,
        request: Request<HealthCheckRequest>,
    ) -> Result<Response<Self::WatchStream>, Status> {
        let permit = self.watches.enter(request.remote_addr())?;
        let status = self.status(&request.get_ref().service)?;
        // the status never changes while the server serves: the stream holds the sender so
        // that it only ends with the client or the server
        let (unchanging, state) = tokio::sync::watch::channel(());
        let stream = crate::watch_stream(state, &self.stopping, permit, move |()| {
            let _held = &unchanging;
            (Some(status), false)
        });
        Ok(Response::new(stream))
    }
}
