//! Prometheus metrics of the services (`--metrics-listen ADDR`): each process builds one
//! registry, registers its service's families (this crate is the one home of their names,
//! all under `jsae_`), and serves it as OpenMetrics text at `http://ADDR/metrics`.
//!
//! The services update their families whether or not a listener serves them (a few atomic
//! stores per fragment, batch or request), so the flag changes nothing but the listener.

mod families;

use std::sync::Arc;

use prometheus_client::registry::Registry;
use tokio::net::TcpListener;

pub use families::{
    ActorMetrics, ActorSample, EmbedderMetrics, EmbedderSample, LearnerMetrics, LearnerSample,
    RecommenderMetrics,
};
pub use prometheus_client::registry::Registry as MetricsRegistry;

/// `--metrics-listen ADDR`, on every service.
#[derive(Debug, Clone, Default, PartialEq, Eq, clap::Args)]
pub struct MetricsFlag {
    /// Serve Prometheus metrics at http://ADDR/metrics (`host:port`; port 0 picks a free one,
    /// logged). Off by default and when empty.
    #[arg(long, env = "JSAE_METRICS_LISTEN", value_name = "ADDR")]
    pub metrics_listen: Option<String>,
}

/// The content type of the OpenMetrics text format (Prometheus reads it).
const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// The registry as OpenMetrics text.
pub fn encode(registry: &Registry) -> String {
    let mut text = String::new();
    // writing into a String cannot fail
    let _ = prometheus_client::encoding::text::encode(&mut text, registry);
    text
}

/// Binds `flag`'s address, if given, and serves `registry` there on this tokio runtime until
/// the process ends; returns the bound address. A bad or busy address is an error, so a
/// service refuses to start rather than run unobserved.
pub async fn serve(
    flag: &MetricsFlag,
    registry: Registry,
) -> std::io::Result<Option<std::net::SocketAddr>> {
    let Some(addr) = flag.metrics_listen.as_deref().filter(|a| !a.is_empty()) else {
        return Ok(None);
    };
    let listener = TcpListener::bind(addr)
        .await
        .map_err(|e| std::io::Error::new(e.kind(), format!("--metrics-listen {addr}: {e}")))?;
    let bound = listener.local_addr()?;
    let registry = Arc::new(registry);
    let app = axum::Router::new().route(
        "/metrics",
        axum::routing::get(move || {
            let registry = registry.clone();
            async move {
                (
                    [(axum::http::header::CONTENT_TYPE, CONTENT_TYPE)],
                    encode(&registry),
                )
            }
        }),
    );
    tokio::spawn(async move {
        if let Err(e) = axum::serve(listener, app).await {
            tracing::warn!("metrics listener: {e}");
        }
    });
    tracing::info!("metrics on http://{bound}/metrics");
    Ok(Some(bound))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn metrics_are_served_as_openmetrics_text() {
        let mut registry = Registry::default();
        let learner = LearnerMetrics::register(&mut registry);
        learner.env_steps.set(4096);
        let flag = MetricsFlag {
            metrics_listen: Some("127.0.0.1:0".into()),
        };
        let addr = serve(&flag, registry)
            .await
            .expect("binds")
            .expect("an address");
        let mut stream = tokio::net::TcpStream::connect(addr)
            .await
            .expect("connects");
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        stream
            .write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            .await
            .expect("writes");
        let mut answer = String::new();
        stream.read_to_string(&mut answer).await.expect("reads");
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
        assert!(answer.contains("jsae_learner_env_steps 4096"), "{answer}");
        assert!(answer.trim_end().ends_with("# EOF"), "{answer}");
    }

    #[tokio::test]
    async fn a_busy_address_is_an_error() {
        let taken = TcpListener::bind("127.0.0.1:0").await.expect("binds");
        let flag = MetricsFlag {
            metrics_listen: Some(taken.local_addr().expect("addr").to_string()),
        };
        let err = serve(&flag, Registry::default()).await.expect_err("busy");
        assert!(err.to_string().contains("--metrics-listen"), "{err}");
    }
}
