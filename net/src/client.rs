//! Following the services' snapshot streams: connect, reassemble chunks, hand each complete
//! snapshot (or event) to a sink, and on any disconnection reconnect with backoff and resume,
//! for as long as the sink wants more. Refusals that retrying cannot fix (the token, a TLS
//! certificate) end the following after [`MAX_CREDENTIAL_REFUSALS`] in a row, with the reason.

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::Backoff;
use crate::security::Security;
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot};
use jsae_wire::{MAX_MESSAGE_BYTES, Reassembler, pb};

/// What the learner's policy stream says.
#[derive(Debug, Clone, PartialEq)]
pub enum PolicyEvent {
    /// A new policy snapshot.
    Snapshot(PolicySnapshot),
    /// Run deterministic evaluation episodes and report them.
    Evaluate(pb::EvalRequest),
    /// The run is over.
    Finish,
    /// Step this many of the actor's environments in each rollout from now on (its share of
    /// the learner's batch; 0: all of them).
    Share(u32),
}

/// Refusals for the credentials in a row (UNAUTHENTICATED, PERMISSION_DENIED, a TLS
/// certificate refused by either side) after which a follower gives up: about 3 s of
/// backoff, enough for a service that is still starting, while a wrong token or certificate
/// never gets better.
pub const MAX_CREDENTIAL_REFUSALS: u32 = 5;

/// Why a follower gave up: the last refusal, for the process to exit with.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{service} {url} refused this process's credentials {count} times in a row: {reason}")]
pub struct GaveUp {
    /// The service followed.
    pub service: &'static str,
    /// Its URL.
    pub url: String,
    /// Refusals in a row.
    pub count: u32,
    /// The last one's reason.
    pub reason: String,
}

/// Whether a failed call was refused for this process's credentials (the token, or a TLS
/// certificate either side refuses): retrying with the same ones cannot succeed.
pub fn refused_credentials(status: &tonic::Status) -> bool {
    use tonic::Code;
    matches!(
        status.code(),
        Code::Unauthenticated | Code::PermissionDenied
    ) || crate::status_reason(status)
        .to_lowercase()
        .contains("certificate")
}

/// Counts refusals for the credentials in a row.
#[derive(Debug)]
struct Refusals {
    service: &'static str,
    url: String,
    count: u32,
}

impl Refusals {
    fn new(service: &'static str, url: &str) -> Self {
        Self {
            service,
            url: url.to_owned(),
            count: 0,
        }
    }

    /// A failed call, logged; the reason to give up once the credentials were refused
    /// [`MAX_CREDENTIAL_REFUSALS`] times in a row.
    fn failed(&mut self, status: &tonic::Status) -> Result<(), GaveUp> {
        let reason = crate::status_reason(status);
        tracing::warn!("{} {}: {reason}", self.service, self.url);
        if !refused_credentials(status) {
            self.count = 0;
            return Ok(());
        }
        self.count += 1;
        if self.count < MAX_CREDENTIAL_REFUSALS {
            return Ok(());
        }
        Err(GaveUp {
            service: self.service,
            url: self.url.clone(),
            count: self.count,
            reason,
        })
    }
}

/// Follows the embedder at `url`: every complete snapshot goes to `sink`; returns when `sink`
/// answers `false` (or `url` is not a valid URL), or gives up when the embedder keeps
/// refusing this process's credentials.
pub async fn watch_embedding<F, Fut>(security: &Security, url: &str, sink: F) -> Result<(), GaveUp>
where
    F: FnMut(EmbeddingSnapshot) -> Fut,
    Fut: Future<Output = bool>,
{
    watch_embedding_counting_losses(security, url, &AtomicU64::new(0), sink).await
}

/// [`watch_embedding`], adding one to `lost` each time the stream opens again after an open
/// one ended: the embedder went away and is back (a restart, or a broken connection), so a
/// client that fed it can feed the new one.
pub async fn watch_embedding_counting_losses<F, Fut>(
    security: &Security,
    url: &str,
    lost: &AtomicU64,
    mut sink: F,
) -> Result<(), GaveUp>
where
    F: FnMut(EmbeddingSnapshot) -> Fut,
    Fut: Future<Output = bool>,
{
    let channel = match security.channel(url) {
        Ok(c) => c,
        Err(e) => {
            tracing::error!("embedder URL {url}: {e}");
            return Ok(());
        }
    };
    let mut opened = false;
    let mut backoff = Backoff::default();
    let mut refusals = Refusals::new("embedder", url);
    loop {
        let mut client = pb::embedder_client::EmbedderClient::new(channel.clone())
            .max_decoding_message_size(MAX_MESSAGE_BYTES);
        match client.watch_embedding(pb::WatchRequest::default()).await {
            Ok(response) => {
                if opened {
                    lost.fetch_add(1, Ordering::Relaxed);
                }
                opened = true;
                backoff.reset();
                refusals.count = 0;
                let mut stream = response.into_inner();
                let mut chunks = Reassembler::default();
                while let Ok(Some(chunk)) = stream.message().await {
                    match chunks.push(chunk) {
                        Ok(Some(done)) => {
                            if !sink(done.into_embedding()).await {
                                return Ok(());
                            }
                        }
                        Ok(None) => {}
                        Err(e) => {
                            tracing::warn!("embedding stream from {url}: {e}");
                            break;
                        }
                    }
                }
                tracing::info!("embedding stream from {url} ended; reconnecting");
            }
            Err(status) => refusals.failed(&status)?,
        }
        tokio::time::sleep(backoff.next_delay()).await;
    }
}

/// Follows the learner at `url`: snapshots, evaluation requests and the end of the run go to
/// `sink`; returns when `sink` answers `false` (or `url` is not a valid URL), or gives up
/// when the learner keeps refusing this process's credentials. `request` says
/// who watches, sent again on every reconnection: an actor (`evaluates`, its id and its
/// rollout's env steps), which the learner counts in its batch and may ask for evaluation
/// episodes while its stream is open, or the default for a follower that only reads the
/// snapshots.
pub async fn watch_policy<F, Fut>(
    security: &Security,
    url: &str,
    request: pb::WatchRequest,
    mut sink: F,
) -> Result<(), GaveUp>
where
    F: FnMut(PolicyEvent) -> Fut,
    Fut: Future<Output = bool>,
{
    use pb::policy_event::Event;
    let channel = match security.channel(url) {
        Ok(c) => c,
        Err(e) => {
            tracing::error!("learner URL {url}: {e}");
            return Ok(());
        }
    };
    let mut backoff = Backoff::default();
    let mut refusals = Refusals::new("learner", url);
    loop {
        let mut client = pb::learner_client::LearnerClient::new(channel.clone())
            .max_decoding_message_size(MAX_MESSAGE_BYTES);
        match client.watch_policy(request).await {
            Ok(response) => {
                backoff.reset();
                refusals.count = 0;
                let mut stream = response.into_inner();
                let mut chunks = Reassembler::default();
                while let Ok(Some(msg)) = stream.message().await {
                    let event = match msg.event {
                        Some(Event::Chunk(chunk)) => match chunks.push(chunk) {
                            Ok(Some(done)) => PolicyEvent::Snapshot(done.into_policy()),
                            Ok(None) => continue,
                            Err(e) => {
                                tracing::warn!("policy stream from {url}: {e}");
                                break;
                            }
                        },
                        Some(Event::Evaluate(request)) => PolicyEvent::Evaluate(request),
                        Some(Event::Finish(_)) => PolicyEvent::Finish,
                        Some(Event::Share(share)) => PolicyEvent::Share(share.envs),
                        None => continue,
                    };
                    if !sink(event).await {
                        return Ok(());
                    }
                }
                tracing::info!("policy stream from {url} ended; reconnecting");
            }
            Err(status) => refusals.failed(&status)?,
        }
        tokio::time::sleep(backoff.next_delay()).await;
    }
}

/// How often [`hold_embedding`] asks again (an embedder that restarted has forgotten).
pub const HOLD_EVERY: std::time::Duration = std::time::Duration::from_secs(2);

/// Asks the embedder at `url` to hold its embedding (`Embedder.HoldEmbedding`), then again
/// every [`HOLD_EVERY`], for as long as the caller polls it: an embedder restarted from its
/// checkpoint holds again within that time. Logs the first answer.
pub async fn hold_embedding(security: &Security, url: &str) {
    let channel = match security.channel(url) {
        Ok(c) => c,
        Err(e) => {
            tracing::error!("embedder URL {url}: {e}");
            return;
        }
    };
    let mut client = pb::embedder_client::EmbedderClient::new(channel);
    let mut held = false;
    loop {
        match client.hold_embedding(pb::HoldRequest {}).await {
            Ok(_) if !held => {
                held = true;
                tracing::info!("the embedder holds its embedding (embedding.hold_from)");
            }
            Ok(_) => {}
            Err(status) => tracing::debug!("holding the embedding at {url}: {status}"),
        }
        tokio::time::sleep(HOLD_EVERY).await;
    }
}
