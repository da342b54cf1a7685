//! A client stream that survives its server: the messages of a queue are sent on one
//! long-lived call, re-opened with backoff whenever it ends.
//!
//! A message leaves the queue only when the call's request stream is polled for it, which the
//! HTTP/2 client does once the stream is open: a call that cannot connect (the service is
//! down, or restarting) takes nothing, so nothing is lost while the service is away. What is
//! lost when a connection breaks is at most the message being written. A request stream that
//! outlives its call (its body not yet dropped) hands a message it takes back to the next one.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::task::{Context, Poll};

use jsae_net::{self as net, Backoff};
use jsae_wire::pb;
use tokio::sync::{Mutex, mpsc};
use tokio_stream::Stream;
use tonic::Code;

/// The queue, shared by the calls one after another.
struct Shared<M> {
    /// The call now open; a request stream of an older one takes nothing more.
    call: AtomicU64,
    /// Whether the open call's stream has been polled (it connected).
    polled: AtomicBool,
    queue: Mutex<Queue<M>>,
}

struct Queue<M> {
    receiver: mpsc::Receiver<M>,
    /// A message an older call's stream took after it was replaced.
    held: Option<M>,
}

/// The next message for call `call`; None when the queue is closed or the call is not the
/// open one.
async fn next<M>(shared: Arc<Shared<M>>, call: u64) -> Option<M> {
    if shared.call.load(Ordering::Acquire) == call {
        shared.polled.store(true, Ordering::Relaxed);
    }
    let mut queue = shared.queue.lock().await;
    if shared.call.load(Ordering::Acquire) != call {
        return None;
    }
    let message = match queue.held.take() {
        Some(m) => m,
        None => queue.receiver.recv().await?,
    };
    if shared.call.load(Ordering::Acquire) != call {
        queue.held = Some(message);
        return None;
    }
    Some(message)
}

type Next<M> = Pin<Box<dyn Future<Output = Option<M>> + Send>>;

/// The request stream of one call: messages taken from the queue as it is polled.
pub struct QueueStream<M> {
    shared: Arc<Shared<M>>,
    call: u64,
    pending: Option<Next<M>>,
}

impl<M: Send + 'static> Stream for QueueStream<M> {
    type Item = M;

    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<M>> {
        let this = self.get_mut();
        let (shared, call) = (this.shared.clone(), this.call);
        let pending = this
            .pending
            .get_or_insert_with(|| Box::pin(next(shared, call)));
        let out = std::task::ready!(pending.as_mut().poll(cx));
        this.pending = None;
        Poll::Ready(out)
    }
}

/// Sends `queue` on calls made by `open` until the queue closes (and is drained).
pub async fn push_forever<M, F, Fut>(name: &'static str, queue: mpsc::Receiver<M>, mut open: F)
where
    M: Send + 'static,
    F: FnMut(QueueStream<M>) -> Fut,
    Fut: Future<Output = Result<pb::PushSummary, tonic::Status>>,
{
    let shared = Arc::new(Shared {
        call: AtomicU64::new(0),
        polled: AtomicBool::new(false),
        queue: Mutex::new(Queue {
            receiver: queue,
            held: None,
        }),
    });
    let mut backoff = Backoff::default();
    for call in 1.. {
        shared.call.store(call, Ordering::Release);
        shared.polled.store(false, Ordering::Relaxed);
        let stream = QueueStream {
            shared: shared.clone(),
            call,
            pending: None,
        };
        let ended = open(stream).await;
        if shared.polled.load(Ordering::Relaxed) {
            backoff.reset();
        }
        match ended {
            Err(status) if status.code() == Code::InvalidArgument => {
                tracing::error!("{name}: a message was refused: {}", status.message());
            }
            Err(status) if status.code() == Code::ResourceExhausted => {
                tracing::error!("{name}: a message was too large: {}", status.message());
            }
            Err(status) if status.code() == Code::Unavailable => {
                // refused or lost: retried with backoff, but said, with the cause
                tracing::warn!("{name}: {}", net::status_reason(&status));
            }
            Err(status) => {
                tracing::debug!("{name}: {} ({:?})", status.message(), status.code());
            }
            Ok(_) => {}
        }
        {
            let queue = shared.queue.lock().await;
            if queue.held.is_none() && queue.receiver.is_closed() && queue.receiver.is_empty() {
                return;
            }
        }
        tokio::time::sleep(backoff.next_delay()).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio_stream::StreamExt;

    /// A call that never connects takes nothing; the next one gets every message in order.
    #[tokio::test]
    async fn a_call_that_cannot_connect_loses_nothing() {
        let (tx, rx) = mpsc::channel(8);
        for i in 0..5 {
            tx.send(i).await.expect("queued");
        }
        drop(tx);
        let mut calls = 0;
        let got = Arc::new(std::sync::Mutex::new(Vec::new()));
        let seen = got.clone();
        push_forever("test", rx, move |mut stream: QueueStream<i32>| {
            calls += 1;
            let seen = seen.clone();
            let first = calls == 1;
            async move {
                if first {
                    drop(stream); // refused before the stream was read
                    return Err(tonic::Status::unavailable("connection refused"));
                }
                while let Some(m) = stream.next().await {
                    seen.lock().expect("lock").push(m);
                }
                Ok(pb::PushSummary::default())
            }
        })
        .await;
        assert_eq!(*got.lock().expect("lock"), vec![0, 1, 2, 3, 4]);
    }

    /// A stream left over from an older call hands the message it took to the open one.
    #[tokio::test]
    async fn a_stale_stream_hands_its_message_on() {
        let (tx, rx) = mpsc::channel(8);
        let shared = Arc::new(Shared {
            call: AtomicU64::new(1),
            polled: AtomicBool::new(false),
            queue: Mutex::new(Queue {
                receiver: rx,
                held: None,
            }),
        });
        let stale = tokio::spawn(next(shared.clone(), 1));
        tokio::task::yield_now().await;
        shared.call.store(2, Ordering::Release);
        tx.send(7).await.expect("queued");
        assert_eq!(stale.await.expect("task"), None);
        assert_eq!(next(shared, 2).await, Some(7));
    }
}
