//! What every service and client shares on the network: binding with TCP_NODELAY, serving a
//! service beside health and reflection, the SIGINT/SIGTERM shutdown signal, a service
//! process's `main`, server streams that follow a watched value, and reconnecting with backoff
//! (connections themselves: [`crate::security::Security::channel`]).

use std::time::Duration;

use tokio::net::TcpListener;

use crate::security::Security;
use jsae_wire::FILE_DESCRIPTOR_SET;

/// Binds `addr` (`host:port`; port 0 picks a free one).
pub async fn bind(addr: &str) -> std::io::Result<TcpListener> {
    TcpListener::bind(addr).await
}

/// The standard `grpc.reflection.v1` service over `jsae.proto`.
pub fn reflection() -> Result<
    tonic_reflection::server::v1::ServerReflectionServer<
        impl tonic_reflection::server::v1::ServerReflection,
    >,
    tonic_reflection::server::Error,
> {
    tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1()
}

/// A future that resolves on SIGINT or SIGTERM. The handlers are installed when this is
/// called (inside a runtime), not when the future is first polled, so a signal that arrives
/// while a service is still starting is not lost (and does not kill it the default way).
pub fn shutdown_signal() -> std::io::Result<impl std::future::Future<Output = ()> + Send + 'static>
{
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let mut interrupt = signal(SignalKind::interrupt())?;
        let mut terminate = signal(SignalKind::terminate())?;
        Ok(async move {
            tokio::select! {
                _ = interrupt.recv() => {}
                _ = terminate.recv() => {}
            }
        })
    }
    #[cfg(not(unix))]
    {
        Ok(async {
            let _ = tokio::signal::ctrl_c().await;
        })
    }
}

/// Exponential backoff between reconnection attempts: 100 ms doubling to 5 s.
#[derive(Debug, Clone)]
pub struct Backoff {
    next: Duration,
}

impl Default for Backoff {
    fn default() -> Self {
        Self {
            next: Duration::from_millis(100),
        }
    }
}

impl Backoff {
    /// The delay before the next attempt (and doubles the one after).
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(Duration::from_secs(5));
        d
    }

    /// Back to the shortest delay, after a success.
    pub fn reset(&mut self) {
        *self = Self::default();
    }
}

/// An error with its causes, outermost first (`transport error: tcp connect error:
/// Connection refused (os error 111)`): tonic's errors and statuses say little at the top.
pub fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        let more = cause.to_string();
        if !text.ends_with(&more) {
            text.push_str(": ");
            text.push_str(&more);
        }
        source = cause.source();
    }
    text
}

/// A status as a reason: its code, its message and the causes under it (a refused
/// connection's OS error), without tonic's metadata dump.
pub fn status_reason(status: &tonic::Status) -> String {
    let mut text = format!("{:?}: {}", status.code(), status.message());
    if let Some(cause) = std::error::Error::source(status) {
        let more = error_chain(cause);
        if !text.ends_with(&more) {
            text.push_str(": ");
            text.push_str(&more);
        }
    }
    text
}

/// Checks a service URL given as `flag` before anything connects: `http://host:port` or
/// `https://host:port` (a bad address would otherwise be retried, silently, forever).
pub fn check_url(flag: &str, url: &str) -> Result<(), String> {
    let uri: tonic::transport::Uri = url
        .parse()
        .map_err(|e| format!("{flag} {url:?}: not a URL ({e}); give http://host:port"))?;
    let scheme_ok = matches!(uri.scheme_str(), Some("http" | "https"));
    if !scheme_ok || uri.host().is_none_or(str::is_empty) {
        return Err(format!("{flag} {url:?}: not a URL like http://host:port"));
    }
    Ok(())
}

/// A future that resolves once `stopping` turns true (or its sender is gone).
pub fn stopped(
    stopping: &tokio::sync::watch::Receiver<bool>,
) -> impl std::future::Future<Output = ()> + Send + use<> {
    let mut s = stopping.clone();
    async move {
        let _ = s.wait_for(|&v| v).await;
    }
}

/// Receives a client stream to its end, handing each message and its index to `each`; ends
/// early with `each`'s error (the messages before it stay handed over), with UNAVAILABLE when
/// `stopping` turns true, and with RESOURCE_EXHAUSTED for a message above the size limit.
/// Returns the number of messages handed over.
pub async fn receive_all<M, F, Fut>(
    mut stream: tonic::Streaming<M>,
    stopping: &tokio::sync::watch::Receiver<bool>,
    service: &str,
    mut each: F,
) -> Result<u64, tonic::Status>
where
    F: FnMut(u64, M) -> Fut,
    Fut: std::future::Future<Output = Result<(), tonic::Status>>,
{
    let stop = stopped(stopping);
    tokio::pin!(stop);
    let mut count = 0;
    loop {
        let msg = tokio::select! {
            m = stream.message() => m.map_err(jsae_wire::receive_error)?,
            () = &mut stop => return Err(jsae_wire::RpcError::shutting_down(service).into()),
        };
        let Some(msg) = msg else { return Ok(count) };
        each(count, msg).await?;
        count += 1;
    }
}

/// The tokio runtime of a service process: two worker threads (the model work runs on its
/// own threads).
pub fn runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
}

/// Why serving stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The reflection service could not be built.
    #[error("reflection: {0}")]
    Reflection(#[from] tonic_reflection::server::Error),
    /// The transport failed.
    #[error("{0}")]
    Transport(#[from] tonic::transport::Error),
}

/// How long a server waits, once shutting down, for its open calls to end before it drops
/// their connections.
pub const SHUTDOWN_GRACE: std::time::Duration = std::time::Duration::from_secs(5);

/// Most HTTP/2 streams (calls) one connection may have open at once (its SETTINGS); the
/// long-lived ones have their own, lower caps (`streams`).
pub const MAX_STREAMS_PER_CONNECTION: u32 = 256;

/// How often a server pings each connection's peer (HTTP/2 PING), and how long it waits for
/// the answer: a peer whose host vanished without closing the connection is found within
/// twice this, and its streams end (an actor asked for the evaluation is then replaced).
pub const KEEPALIVE: std::time::Duration = std::time::Duration::from_secs(20);

/// Serves `service` on `listener` beside `grpc.health.v1.Health` (reporting it SERVING) and
/// server reflection, until `shutdown` resolves; a connection reaches it only once it has
/// spoken ([`crate::accept`]). Every service of the project is served so.
/// `security` decides TLS and the token, which every service but health requires.
/// `receive_window`: the HTTP/2 flow-control window of each call and of each connection, in
/// bytes (None: hyper's default, about 1 MB): how much a client may send that the service has
/// not read, so a small one carries the service's backpressure to its clients.
pub async fn serve<S>(
    service: S,
    listener: TcpListener,
    security: &Security,
    receive_window: Option<u32>,
    shutdown: impl std::future::Future<Output = ()> + Send,
) -> Result<(), ServeError>
where
    S: tonic::codegen::Service<
            tonic::codegen::http::Request<tonic::body::Body>,
            Response = tonic::codegen::http::Response<tonic::body::Body>,
            Error = std::convert::Infallible,
        > + tonic::server::NamedService
        + Clone
        + Send
        + Sync
        + 'static,
    S::Future: Send + 'static,
{
    let (stopping_tx, stopping) = tokio::sync::watch::channel(false);
    let health_service = crate::health::ServingHealth::new(S::NAME, stopping);
    let mut server = tonic::transport::Server::builder()
        .max_concurrent_streams(Some(MAX_STREAMS_PER_CONNECTION))
        .http2_keepalive_interval(Some(KEEPALIVE))
        .http2_keepalive_timeout(Some(KEEPALIVE))
        .initial_stream_window_size(receive_window)
        .initial_connection_window_size(receive_window);
    if let Some(tls) = security.server_tls() {
        server = server.tls_config(tls)?;
    }
    let (stopped_tx, stopped_rx) = tokio::sync::oneshot::channel::<()>();
    let signal = async move {
        shutdown.await;
        let _ = stopping_tx.send(true);
        let _ = stopped_tx.send(());
    };
    let serving =
        server
            .add_service(health_service)
            .add_service(security.guard(reflection()?))
            .add_service(security.guard(jsae_wire::WatchesClientEnd(
                jsae_wire::TooLargeIsExhausted(service),
            )))
            .serve_with_incoming_shutdown(
                crate::accept::spoken(listener, crate::accept::FIRST_BYTES_TIMEOUT),
                signal,
            );
    tokio::pin!(serving);
    // a graceful shutdown waits for every open call to end; a client that stops reading a
    // server stream never lets it end, so after SHUTDOWN_GRACE its connection is dropped
    let grace = async move {
        if stopped_rx.await.is_ok() {
            tokio::time::sleep(SHUTDOWN_GRACE).await;
        } else {
            std::future::pending::<()>().await;
        }
    };
    tokio::select! {
        served = &mut serving => served?,
        () = grace => tracing::warn!(
            "calls still open {} s after the shutdown began: their connections are dropped",
            SHUTDOWN_GRACE.as_secs()
        ),
    }
    Ok(())
}

/// A server stream that follows `state`: for the current value and every change after it,
/// `events` gives the messages to send and whether they are the last. The stream ends then,
/// when the client goes away, or when `stopping` turns true; `permit` (its place among the
/// service's open streams) is freed then. The messages are taken one at a time as the
/// client reads (one waits in the channel), so a client that stops reading holds one
/// message, not every message of a snapshot.
pub fn watch_stream<T, M, I, F>(
    mut state: tokio::sync::watch::Receiver<T>,
    stopping: &tokio::sync::watch::Receiver<bool>,
    permit: crate::streams::StreamPermit,
    mut events: F,
) -> tokio_stream::wrappers::ReceiverStream<Result<M, tonic::Status>>
where
    T: Clone + Send + Sync + 'static,
    M: Send + 'static,
    I: IntoIterator<Item = M>,
    I::IntoIter: Send,
    F: FnMut(&T) -> (I, bool) + Send + 'static,
{
    let stop = stopped(stopping);
    let (tx, rx) = tokio::sync::mpsc::channel(1);
    tokio::spawn(async move {
        let _permit = permit;
        tokio::pin!(stop);
        loop {
            let now = state.borrow_and_update().clone();
            let (messages, last) = events(&now);
            for m in messages {
                if tx.send(Ok(m)).await.is_err() {
                    return;
                }
            }
            if last {
                return;
            }
            tokio::select! {
                r = state.changed() => if r.is_err() { return },
                () = tx.closed() => return,
                () = &mut stop => return,
            }
        }
    });
    tokio_stream::wrappers::ReceiverStream::new(rx)
}

/// How long an interrupted service waits for its training thread to leave the step it is in
/// (an update of a very large model can take minutes) before it exits without it.
pub const TRAINING_STOP_GRACE: std::time::Duration = std::time::Duration::from_secs(10);

/// Joins a service's training thread once its server has stopped. When `interrupted` (a
/// signal, not the end of the run), it waits at most [`TRAINING_STOP_GRACE`] and gives None
/// if the thread is still busy then (logged): what that step would have written is lost as
/// in a crash, and the checkpoints on disk stay as they are.
pub async fn join_training<T: Send + 'static>(
    thread: std::thread::JoinHandle<T>,
    interrupted: bool,
    service: &str,
) -> Option<std::thread::Result<T>> {
    // polled, not joined on a blocking task: the runtime's end would wait for that task, so
    // for the thread, however long its step takes
    let deadline = tokio::time::Instant::now() + TRAINING_STOP_GRACE;
    while !thread.is_finished() {
        if interrupted && tokio::time::Instant::now() >= deadline {
            tracing::warn!(
                "{service}: the training thread is still busy {} s after the signal; exiting \
                 without it (the checkpoints on disk stay as they are)",
                TRAINING_STOP_GRACE.as_secs()
            );
            return None;
        }
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    Some(thread.join())
}

/// Why a service process stops with an error: exit 1, or 2 for a configuration found bad
/// only after start (a run directory's settings that were still to be written).
#[derive(Debug)]
pub struct Failure {
    code: u8,
    message: String,
}

impl Failure {
    /// A bad configuration (exit 2).
    pub fn config(reason: impl std::fmt::Display) -> Self {
        Self {
            code: 2,
            message: reason.to_string(),
        }
    }
}

impl<E: std::fmt::Display> From<E> for Failure {
    fn from(e: E) -> Self {
        Self {
            code: 1,
            message: format!("{e:#}"),
        }
    }
}

/// The SIGINT/SIGTERM future handed to a service's body.
pub type Shutdown = std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send + 'static>>;

/// The one `main` of every service process (`name` prefixes its messages): a bad
/// configuration (`config` is `Err`) exits 2 with a one-line reason before anything starts;
/// then logging, the runtime and the SIGINT/SIGTERM future, and `body` runs with the
/// configuration and that future. Its `Ok` value goes to `done` (which reports it) and the
/// process exits 0; a [`Failure`] is printed and exits with its code.
pub fn service_main<C, T, Fut>(
    name: &str,
    config: Result<C, String>,
    body: impl FnOnce(C, Shutdown) -> Fut,
    done: impl FnOnce(T),
) -> std::process::ExitCode
where
    Fut: std::future::Future<Output = Result<T, Failure>>,
{
    use std::process::ExitCode;
    let config = match config {
        Ok(c) => c,
        Err(reason) => {
            crate::logging::report_failure(name, &reason);
            return ExitCode::from(2);
        }
    };
    crate::logging::init_logging();
    let runtime = match runtime() {
        Ok(r) => r,
        Err(e) => {
            crate::logging::report_failure(name, &e.to_string());
            return ExitCode::FAILURE;
        }
    };
    let result = runtime.block_on(async {
        let shutdown = shutdown_signal()?;
        body(config, Box::pin(shutdown)).await
    });
    runtime.shutdown_timeout(Duration::from_secs(2));
    match result {
        Ok(value) => {
            done(value);
            ExitCode::SUCCESS
        }
        Err(failure) => {
            crate::logging::report_failure(name, &failure.message);
            ExitCode::from(failure.code)
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    use tokio_stream::StreamExt;

    use crate::streams::{Cap, StreamLimit};

    #[tokio::test]
    async fn a_stream_takes_its_messages_as_the_client_reads_and_frees_its_place_at_the_end() {
        let taken = Arc::new(AtomicUsize::new(0));
        let (state_tx, state) = tokio::sync::watch::channel(());
        let (_stop_tx, stopping) = tokio::sync::watch::channel(false);
        let limit = StreamLimit::new("Test", Cap { n: 1, name: "ONE" }, Cap { n: 1, name: "ONE" });
        let permit = limit.enter(None).expect("a place");
        let counted = taken.clone();
        let mut stream = super::watch_stream(state, &stopping, permit, move |()| {
            let counted = counted.clone();
            // a snapshot of 1,000 chunks, each counted when it is cut
            let chunks = (0..1000).inspect(move |_| {
                counted.fetch_add(1, Ordering::SeqCst);
            });
            (chunks, false)
        });
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
        assert!(
            taken.load(Ordering::SeqCst) <= 2,
            "a client that does not read holds at most one message waiting: {} cut",
            taken.load(Ordering::SeqCst)
        );
        for expected in 0..10 {
            let got = stream.next().await.expect("a message").expect("ok");
            assert_eq!(got, expected);
        }
        assert!(taken.load(Ordering::SeqCst) <= 12);
        assert_eq!(limit.open(), 1);
        drop(stream);
        drop(state_tx);
        for _ in 0..50 {
            if limit.open() == 0 {
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(10)).await;
        }
        assert_eq!(limit.open(), 0, "the place is free once the client is gone");
    }
}
