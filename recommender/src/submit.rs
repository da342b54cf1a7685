//! `SubmitSessions`: a call's sessions are checked one at a time, the good ones written to the
//! call's staging file as they arrive (in batches of [`STAGE_BATCH_BYTES`], off the async
//! threads), and committed to the session store all at once when the stream ends cleanly. A
//! call that fails (a broken or cancelled stream, a limit passed, a store error) stores
//! nothing: its staging file is deleted, and the error says so. Sessions whose `session_id`
//! is stored already are counted as duplicates, not stored again.
//!
//! Memory: a call holds one message, the batch being staged and the ids it staged (8 bytes
//! each), never its stream. The limits below bound what the calls together hold and write.
//!
//! Fairness: a call holds one of [`MAX_CONCURRENT_CALLS`] slots only while it sends (it ends
//! after [`SUBMIT_IDLE_TIMEOUT`] without a message, or [`SUBMIT_CALL_TIMEOUT`] in all); a
//! call that finds every slot taken waits its turn (up to [`SLOT_WAIT`]), and one connection
//! has at most [`MAX_CALLS_PER_CONNECTION`] calls at once.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::Duration;

use jsae_envs::recsys::sessions::{Session, check_session};
use jsae_envs::recsys::staging::{Staged, StagedSessions};
use jsae_net::streams::{Cap, ConnectionGuard, CountedPlace, PerConnection};
use jsae_wire::RpcError;
use jsae_wire::pb;
use prost::Message;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tonic::{Code, Status, Streaming};

use crate::scoring::Recommender;

/// Largest message the Recommender decodes (4 MiB; a larger one is RESOURCE_EXHAUSTED). A
/// session at every limit (10,000 purchases of 256-byte ids) takes about 2.8 MB; a
/// `Recommend` request of 1,000 ids about 260 kB.
pub const MAX_REQUEST_BYTES: usize = 4 * 1024 * 1024;
/// Most sessions one call may carry; more is RESOURCE_EXHAUSTED (nothing stored).
pub const MAX_SESSIONS_PER_CALL: u64 = 100_000;
/// Most bytes (encoded sessions) one call may carry; more is RESOURCE_EXHAUSTED (nothing
/// stored). The largest commit a call can ask for.
pub const MAX_CALL_BYTES: u64 = 64 * 1024 * 1024;
/// Most bytes all the calls in progress together may have sent (and so staged on disk); a
/// message past it is RESOURCE_EXHAUSTED for its call (nothing of it stored).
pub const MAX_BYTES_IN_FLIGHT: u64 = 128 * 1024 * 1024;
/// Most calls in progress at once. Each holds at most one decoded message (up to about
/// 60 MB for 4 MiB of the smallest purchases, typically a few MB), so this bounds the calls'
/// memory. A call beyond it waits for a slot, in arrival order, up to [`SLOT_WAIT`].
pub const MAX_CONCURRENT_CALLS: usize = 4;
/// Most calls one connection may have in progress (or waiting) at once; one more is
/// RESOURCE_EXHAUSTED before it reads anything, so one client cannot queue for every slot.
pub const MAX_CALLS_PER_CONNECTION: usize = 2;
/// Most calls waiting for a slot at once; one more is RESOURCE_EXHAUSTED at once.
pub const MAX_WAITING_CALLS: usize = 64;
/// How long a call waits for a slot before it is RESOURCE_EXHAUSTED: longer than
/// [`SUBMIT_IDLE_TIMEOUT`], so calls that hold slots without sending cannot keep a waiting
/// call out.
pub const SLOT_WAIT: Duration = Duration::from_secs(20);
/// A call that sends no message for this long (from its start, or since its last message)
/// ends DEADLINE_EXCEEDED, nothing of it stored, and gives its slot to the next.
pub const SUBMIT_IDLE_TIMEOUT: Duration = Duration::from_secs(10);
/// The longest a call may take from its start (64 MiB at 0.5 MB/s); past it the call ends
/// DEADLINE_EXCEEDED, nothing of it stored.
pub const SUBMIT_CALL_TIMEOUT: Duration = Duration::from_secs(120);
/// Errors listed in a SubmitSummary (the count of rejected sessions is always exact).
pub const MAX_ERRORS_LISTED: usize = 100;
/// Checked sessions gathered before they are written to the staging file together.
const STAGE_BATCH_BYTES: u64 = 1024 * 1024;

/// What the SubmitSessions calls in progress use: slots ([`MAX_CONCURRENT_CALLS`], handed
/// out in arrival order), calls per connection ([`MAX_CALLS_PER_CONNECTION`]), calls
/// waiting ([`MAX_WAITING_CALLS`]) and bytes ([`MAX_BYTES_IN_FLIGHT`]); shared by the
/// service's clones.
#[derive(Debug, Clone)]
pub struct SubmitBudget {
    slots: Arc<Semaphore>,
    waiting: Arc<AtomicUsize>,
    /// Calls in progress or waiting, per connection (its peer's address).
    connections: PerConnection,
    bytes: Arc<AtomicU64>,
}

impl Default for SubmitBudget {
    fn default() -> Self {
        Self {
            slots: Arc::new(Semaphore::new(MAX_CONCURRENT_CALLS)),
            waiting: Arc::default(),
            connections: PerConnection::new(
                "SubmitSessions",
                Cap {
                    n: MAX_CALLS_PER_CONNECTION,
                    name: "MAX_CALLS_PER_CONNECTION",
                },
            ),
            bytes: Arc::default(),
        }
    }
}

impl SubmitBudget {
    /// Calls in progress now (holding a slot).
    pub fn calls(&self) -> usize {
        MAX_CONCURRENT_CALLS - self.slots.available_permits()
    }

    /// Bytes the calls in progress have sent.
    pub fn bytes(&self) -> u64 {
        self.bytes.load(Ordering::SeqCst)
    }

    /// A call's share, once a slot is free (waiting at most [`SLOT_WAIT`], after the calls
    /// that came before it), unless its connection has [`MAX_CALLS_PER_CONNECTION`] calls
    /// already or [`MAX_WAITING_CALLS`] wait.
    async fn enter(&self, connection: Option<SocketAddr>) -> Result<CallBudget, RpcError> {
        let connection = self.connections.enter(connection)?;
        let (_waiting, waiting) = CountedPlace::take(&self.waiting);
        if waiting >= MAX_WAITING_CALLS {
            return Err(RpcError::ResourceExhausted(format!(
                "{MAX_CONCURRENT_CALLS} SubmitSessions calls are in progress and \
                 {MAX_WAITING_CALLS} wait (MAX_WAITING_CALLS): try again later"
            )));
        }
        let slot = tokio::time::timeout(SLOT_WAIT, self.slots.clone().acquire_owned())
            .await
            .map_err(|_| {
                RpcError::ResourceExhausted(format!(
                    "all {MAX_CONCURRENT_CALLS} SubmitSessions slots (MAX_CONCURRENT_CALLS) stayed \
                     busy for {} s (SLOT_WAIT): try again later",
                    SLOT_WAIT.as_secs()
                ))
            })?
            .map_err(|_| RpcError::shutting_down("recommender"))?;
        Ok(CallBudget {
            budget: self.clone(),
            bytes: 0,
            _slot: slot,
            _connection: connection,
        })
    }
}

/// One call's share of a [`SubmitBudget`], given back when the call ends.
#[derive(Debug)]
struct CallBudget {
    budget: SubmitBudget,
    bytes: u64,
    _slot: OwnedSemaphorePermit,
    _connection: ConnectionGuard,
}

impl CallBudget {
    /// Counts `n` more bytes sent by the call, if they fit both limits.
    fn take(&mut self, n: u64) -> Result<(), RpcError> {
        if self.bytes + n > MAX_CALL_BYTES {
            return Err(RpcError::ResourceExhausted(format!(
                "the call's sessions pass {MAX_CALL_BYTES} bytes (MAX_CALL_BYTES): send them in \
                 smaller calls"
            )));
        }
        let all = self.budget.bytes.fetch_add(n, Ordering::SeqCst) + n;
        self.bytes += n;
        if all > MAX_BYTES_IN_FLIGHT {
            return Err(RpcError::ResourceExhausted(format!(
                "the calls in progress pass {MAX_BYTES_IN_FLIGHT} bytes together \
                 (MAX_BYTES_IN_FLIGHT): try again when others have ended"
            )));
        }
        Ok(())
    }
}

impl Drop for CallBudget {
    fn drop(&mut self) {
        self.budget.bytes.fetch_sub(self.bytes, Ordering::SeqCst);
    }
}

/// The next message of a call, or DEADLINE_EXCEEDED once [`SUBMIT_IDLE_TIMEOUT`] passes
/// without one or the call's `deadline` passes.
async fn next_message(
    stream: &mut Streaming<pb::Session>,
    deadline: tokio::time::Instant,
) -> Result<Option<pb::Session>, Status> {
    let idle = tokio::time::Instant::now() + SUBMIT_IDLE_TIMEOUT;
    match tokio::time::timeout_at(idle.min(deadline), stream.message()).await {
        Ok(message) => message.map_err(broken_stream),
        Err(_) if idle <= deadline => Err(Status::deadline_exceeded(format!(
            "no message for {} s (SUBMIT_IDLE_TIMEOUT)",
            SUBMIT_IDLE_TIMEOUT.as_secs()
        ))),
        Err(_) => Err(Status::deadline_exceeded(format!(
            "the call took over {} s (SUBMIT_CALL_TIMEOUT): send the sessions in smaller calls",
            SUBMIT_CALL_TIMEOUT.as_secs()
        ))),
    }
}

/// A call's error, saying that nothing of the call was stored.
fn nothing_stored(status: impl Into<Status>) -> Status {
    let status = status.into();
    Status::new(
        status.code(),
        format!(
            "{}; nothing of this call was stored: send it again (sessions stored already are \
             counted as duplicates, not stored twice)",
            status.message()
        ),
    )
}

/// The error of a stream that broke: a message over [`MAX_REQUEST_BYTES`] is
/// RESOURCE_EXHAUSTED ([`jsae_wire::receive_error`]), with this service's limit.
fn broken_stream(status: Status) -> Status {
    let status = jsae_wire::receive_error(status);
    if status.code() != Code::ResourceExhausted {
        return status;
    }
    Status::resource_exhausted(format!(
        "a message over {MAX_REQUEST_BYTES} bytes (MAX_REQUEST_BYTES): one session per message, \
         within the limits of a session"
    ))
}

fn internal(e: impl std::fmt::Display) -> RpcError {
    RpcError::Internal(format!("session store: {e}"))
}

/// A call's checked sessions on their way to its staging file.
struct Stager {
    /// The staging file (taken out while a batch is written to it).
    staged: Option<StagedSessions>,
    batch: Vec<Session>,
    batch_bytes: u64,
    duplicates: u64,
}

impl Stager {
    /// Adds a checked session (`bytes` encoded), writing the batch out when it is full.
    async fn push(&mut self, session: Session, bytes: u64) -> Result<(), RpcError> {
        self.batch.push(session);
        self.batch_bytes += bytes;
        if self.batch_bytes >= STAGE_BATCH_BYTES {
            self.write_batch().await?;
        }
        Ok(())
    }

    /// Writes the batch to the staging file off the async threads. Should the call be
    /// cancelled meanwhile, the staging file is deleted when the write returns.
    async fn write_batch(&mut self) -> Result<(), RpcError> {
        let batch = std::mem::take(&mut self.batch);
        self.batch_bytes = 0;
        if batch.is_empty() {
            return Ok(());
        }
        let mut staged = self
            .staged
            .take()
            .ok_or_else(|| internal("the staging file was lost to an earlier error"))?;
        let (staged, duplicates) = tokio::task::spawn_blocking(move || {
            let mut duplicates = 0;
            for s in &batch {
                if staged.push(s)? == Staged::Duplicate {
                    duplicates += 1;
                }
            }
            Ok::<_, jsae_envs::RecsysError>((staged, duplicates))
        })
        .await
        .map_err(internal)?
        .map_err(internal)?;
        self.staged = Some(staged);
        self.duplicates += duplicates;
        Ok(())
    }
}

/// Receives one call: checks each session, stages the good ones and commits them when the
/// stream ends cleanly; any error before the commit stores nothing.
pub(crate) async fn receive_sessions(
    inner: &Arc<Recommender>,
    budget: &SubmitBudget,
    request: tonic::Request<Streaming<pb::Session>>,
) -> Result<pb::SubmitSummary, Status> {
    let deadline = tokio::time::Instant::now() + SUBMIT_CALL_TIMEOUT;
    let peer = request.remote_addr();
    let client_end = jsae_wire::ClientEnd::of(&request);
    let mut stream = request.into_inner();
    let mut call = budget.enter(peer).await.map_err(nothing_stored)?;
    let mut stager = inner.stage()?.map(|staged| Stager {
        staged: Some(staged),
        batch: Vec::new(),
        batch_bytes: 0,
        duplicates: 0,
    });
    let mut summary = pb::SubmitSummary::default();
    let mut index: u64 = 0;
    while let Some(message) = next_message(&mut stream, deadline)
        .await
        .map_err(nothing_stored)?
    {
        let bytes = message.encoded_len() as u64;
        call.take(bytes).map_err(nothing_stored)?;
        if index >= MAX_SESSIONS_PER_CALL {
            return Err(nothing_stored(RpcError::ResourceExhausted(format!(
                "more than {MAX_SESSIONS_PER_CALL} sessions in one call \
                 (MAX_SESSIONS_PER_CALL): send them in smaller calls"
            ))));
        }
        let session = crate::session_from_wire(message);
        match check_session(&session) {
            Ok(()) => match &mut stager {
                Some(stager) => stager.push(session, bytes).await.map_err(nothing_stored)?,
                // no store: counted, not kept
                None => {
                    summary.sessions_accepted += 1;
                    summary.purchases_accepted += session.purchases.len() as u64;
                }
            },
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
    // tonic ends the stream above on the client's cancel as on its own end: only the end
    // the client sent commits
    if client_end.is_some_and(|end| !end.ended()) {
        return Err(nothing_stored(RpcError::Cancelled(
            "the client cancelled the call before it ended its stream".into(),
        )));
    }
    if index == 0 {
        return Err(RpcError::InvalidArgument("no sessions: the stream was empty".into()).into());
    }
    if let Some(mut stager) = stager {
        stager.write_batch().await.map_err(nothing_stored)?;
        let inner = inner.clone();
        let staged = stager
            .staged
            .take()
            .ok_or_else(|| nothing_stored(internal("the staging file was lost")))?;
        let outcome = tokio::task::spawn_blocking(move || inner.commit(staged))
            .await
            .map_err(|e| nothing_stored(internal(e)))?
            .map_err(nothing_stored)?;
        summary.sessions_accepted = outcome.stored;
        summary.purchases_accepted = outcome.purchases;
        summary.sessions_duplicate = stager.duplicates + outcome.duplicates;
    }
    if summary.sessions_rejected > summary.errors.len() as u64 {
        let more = summary.sessions_rejected - summary.errors.len() as u64;
        summary
            .errors
            .push(format!("... and {more} more rejected sessions"));
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MIB: u64 = 1024 * 1024;

    fn peer(port: u16) -> Option<SocketAddr> {
        Some(SocketAddr::from(([127, 0, 0, 1], port)))
    }

    #[tokio::test]
    async fn calls_stay_within_their_bytes_the_bytes_in_flight_and_the_calls_at_once() {
        let budget = SubmitBudget::default();
        let mut a = budget.enter(peer(1)).await.expect("a first call");
        a.take(MAX_CALL_BYTES - 1).expect("within MAX_CALL_BYTES");
        let over = a.take(2).expect_err("over MAX_CALL_BYTES");
        assert!(over.to_string().contains("MAX_CALL_BYTES"), "{over}");
        let mut b = budget.enter(peer(2)).await.expect("a second call");
        b.take(MAX_BYTES_IN_FLIGHT - MAX_CALL_BYTES)
            .expect("within");
        let mut c = budget.enter(peer(3)).await.expect("a third call");
        let over = c.take(2 * MIB).expect_err("over MAX_BYTES_IN_FLIGHT");
        assert!(over.to_string().contains("MAX_BYTES_IN_FLIGHT"), "{over}");
        drop(c);
        drop(a);
        assert_eq!(budget.bytes(), MAX_BYTES_IN_FLIGHT - MAX_CALL_BYTES);
        let mut d = budget.enter(peer(4)).await.expect("room again");
        d.take(2 * MIB).expect("within");
        drop((b, d));
        assert_eq!((budget.calls(), budget.bytes()), (0, 0));
    }

    #[tokio::test]
    async fn one_connection_holds_at_most_its_share_of_the_calls() {
        let budget = SubmitBudget::default();
        let held: Vec<CallBudget> = calls_from(&budget, peer(9), MAX_CALLS_PER_CONNECTION).await;
        let refused = budget.enter(peer(9)).await.expect_err("one call too many");
        assert!(
            refused.to_string().contains("MAX_CALLS_PER_CONNECTION"),
            "{refused}"
        );
        budget
            .enter(peer(10))
            .await
            .expect("another connection has room");
        drop(held);
        budget
            .enter(peer(9))
            .await
            .expect("the connection's calls ended");
    }

    #[tokio::test(start_paused = true)]
    async fn a_call_past_the_slots_waits_its_turn_then_gives_up() {
        let budget = SubmitBudget::default();
        let mut held = Vec::new();
        for port in 0..MAX_CONCURRENT_CALLS as u16 {
            held.push(budget.enter(peer(port)).await.expect("a slot"));
        }
        assert_eq!(budget.calls(), MAX_CONCURRENT_CALLS);
        // a slot freed while it waits: the waiting call takes it
        let waiting = {
            let budget = budget.clone();
            tokio::spawn(async move { budget.enter(peer(100)).await.map(|_| ()) })
        };
        tokio::time::sleep(SLOT_WAIT / 2).await;
        held.pop();
        waiting.await.expect("task").expect("the freed slot");
        // no slot freed within SLOT_WAIT: RESOURCE_EXHAUSTED
        held.push(budget.enter(peer(50)).await.expect("the last slot"));
        let refused = budget
            .enter(peer(101))
            .await
            .expect_err("every slot stayed busy");
        assert!(refused.to_string().contains("SLOT_WAIT"), "{refused}");
    }

    async fn calls_from(
        budget: &SubmitBudget,
        at: Option<SocketAddr>,
        n: usize,
    ) -> Vec<CallBudget> {
        let mut calls = Vec::new();
        for _ in 0..n {
            calls.push(budget.enter(at).await.expect("room"));
        }
        calls
    }

    /// A request body of one framed session, then the reset a client's cancel is.
    struct OneSessionThenReset(Option<bytes::Bytes>);

    impl http_body::Body for OneSessionThenReset {
        type Data = bytes::Bytes;
        type Error = Status;

        fn poll_frame(
            mut self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<Option<Result<http_body::Frame<bytes::Bytes>, Status>>> {
            std::task::Poll::Ready(Some(match self.0.take() {
                Some(data) => Ok(http_body::Frame::data(data)),
                None => Err(Status::cancelled("stream reset by the client")),
            }))
        }
    }

    #[tokio::test]
    async fn a_stream_the_client_cancelled_commits_nothing() {
        // tonic reads the cancel as the stream's end; the call's ClientEnd says it was not
        let store = std::env::temp_dir().join(format!("jsae-cancel-unit-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&store);
        let mut c = jsae_settings::TrainConfig::defaults(
            jsae_settings::EnvName::Recommender,
            jsae_settings::Algo::Jsae,
        );
        let r = &mut c.environment.recommender;
        r.source = jsae_settings::SessionSource::Synthetic;
        (r.top_n, r.synthetic.items, r.synthetic.sessions) = (20, 20, 100);
        r.store_dir = store.clone();
        let rec = Recommender::new(
            &c,
            crate::baseline::PolicyChoice::Popular,
            jsae_nn::DeviceKind::Flex,
        )
        .expect("recommender");
        let session = pb::Session {
            session_id: "cancelled".into(),
            purchases: vec![pb::Purchase {
                item_id: "item-1".into(),
                price: 1.0,
                time_unix_ms: 0,
            }],
        };
        let message = session.encode_to_vec();
        let mut framed = vec![0u8];
        framed.extend((message.len() as u32).to_be_bytes());
        framed.extend(message);
        let body = OneSessionThenReset(Some(framed.into()));
        let stream = Streaming::new_request(
            tonic_prost::ProstDecoder::<pb::Session>::default(),
            body,
            None,
            None,
        );
        let mut request = tonic::Request::new(stream);
        request
            .extensions_mut()
            .insert(jsae_wire::ClientEnd::default());
        let refused = receive_sessions(&Arc::new(rec), &SubmitBudget::default(), request)
            .await
            .expect_err("a cancelled call");
        assert_eq!(refused.code(), tonic::Code::Cancelled, "{refused:?}");
        assert!(
            refused
                .message()
                .contains("nothing of this call was stored"),
            "{refused:?}"
        );
        let log = std::fs::read(store.join("sessions.jsonl")).unwrap_or_default();
        assert!(log.is_empty(), "stored: {}", String::from_utf8_lossy(&log));
        let _ = std::fs::remove_dir_all(&store);
    }
}
