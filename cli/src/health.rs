//! `jsae health`: a gRPC health check (grpc.health.v1) for container healthchecks, where no
//! grpcurl is installed. Exit 0 when the service answers SERVING, 1 otherwise.

use std::time::Duration;

use jsae_net::security::SecurityFlags;
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};

/// The health check's command line.
#[derive(Debug, Clone, clap::Args)]
#[command(mut_arg("tls_client_ca", |a| a.hide(true)))] // a server's flag
pub struct HealthArgs {
    /// The service's address (`http://host:port`, or `host:port`).
    #[arg(
        long,
        env = "JSAE_HEALTH_ADDR",
        default_value = "http://127.0.0.1:50051"
    )]
    pub addr: String,
    /// The service name to ask about ("" = the server as a whole).
    #[arg(long, default_value = "")]
    pub service: String,
    /// Give up after this many milliseconds.
    #[arg(long, default_value_t = 3000)]
    pub timeout_ms: u64,
    /// `--tls-ca` (and a client certificate for mutual TLS); health needs no token.
    #[command(flatten)]
    pub security: SecurityFlags,
}

/// Asks once; `Ok("SERVING")` when the answer is SERVING.
pub async fn check(args: &HealthArgs) -> Result<&'static str, String> {
    let security = args.security.load()?;
    let (channel, url) = crate::oneshot::connect(&args.addr, &security)?;
    let mut client = HealthClient::new(channel);
    let call = client.check(HealthCheckRequest {
        service: args.service.clone(),
    });
    let answer = tokio::time::timeout(Duration::from_millis(args.timeout_ms), call)
        .await
        .map_err(|_| format!("{url}: no answer in {} ms", args.timeout_ms))?
        .map_err(|s| crate::oneshot::reason(&url, &s))?
        .into_inner();
    match answer.status() {
        ServingStatus::Serving => Ok("SERVING"),
        other => Err(format!("{url}: {other:?}")),
    }
}

/// Runs the check: exit 0 when SERVING, 1 otherwise (the reason on stderr).
pub fn main(args: HealthArgs) -> std::process::ExitCode {
    crate::oneshot::run("jsae health", check(&args))
}
