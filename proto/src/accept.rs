//! Accepting connections for a server: an accepted TCP connection reaches the server only
//! once it has sent its first [`FIRST_BYTES`] bytes (the HTTP/2 client preface; a TLS
//! ClientHello is longer), within [`FIRST_BYTES_TIMEOUT`]. A connection that stays silent is
//! closed then, and at most [`MAX_SILENT_CONNECTIONS`] wait at once (past that the one that
//! has waited longest is closed for the newcomer), so sockets that never speak can neither
//! pile up and take every file descriptor nor keep a real client out.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, oneshot};
use tokio_stream::wrappers::ReceiverStream;

/// How long an accepted connection has to send its first bytes.
pub const FIRST_BYTES_TIMEOUT: Duration = Duration::from_secs(10);
/// The bytes a connection must send before the server sees it: HTTP/2's client preface.
pub const FIRST_BYTES: usize = 24;
/// Most accepted connections that have not yet sent their first bytes.
pub const MAX_SILENT_CONNECTIONS: usize = 256;

/// Connections not yet spoken, oldest first: a number and what closes it.
type Silent = VecDeque<(u64, oneshot::Sender<()>)>;

/// The connections of `listener` that spoke within `timeout` (TCP_NODELAY on), for
/// `serve_with_incoming`. The listener is dropped when the stream is.
pub fn spoken(
    listener: TcpListener,
    timeout: Duration,
) -> ReceiverStream<std::io::Result<TcpStream>> {
    let (tx, rx) = mpsc::channel(64);
    // the connections still silent, oldest first, each with what closes it
    let silent: Arc<Mutex<Silent>> = Arc::default();
    tokio::spawn(async move {
        for n in 0u64.. {
            let accepted = tokio::select! {
                () = tx.closed() => break,
                accepted = listener.accept() => accepted,
            };
            let stream = match accepted {
                Ok((stream, _)) => stream,
                Err(e) => {
                    // out of descriptors, say: wait a moment rather than spin
                    tracing::warn!("accepting a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            };
            let (close, closed) = oneshot::channel();
            {
                let mut waiting = silent.lock().unwrap_or_else(|e| e.into_inner());
                if waiting.len() >= MAX_SILENT_CONNECTIONS
                    && let Some((_, oldest)) = waiting.pop_front()
                {
                    let _ = oldest.send(());
                }
                waiting.push_back((n, close));
            }
            let _ = stream.set_nodelay(true);
            let (tx, silent) = (tx.clone(), silent.clone());
            tokio::spawn(async move {
                let spoke = tokio::select! {
                    spoke = first_bytes(&stream, timeout) => spoke,
                    _ = closed => false,
                };
                silent
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .retain(|(id, _)| *id != n);
                if spoke {
                    let _ = tx.send(Ok(stream)).await;
                }
            });
        }
    });
    ReceiverStream::new(rx)
}

/// Whether `stream` holds [`FIRST_BYTES`] bytes within `timeout` (without reading them).
async fn first_bytes(stream: &TcpStream, timeout: Duration) -> bool {
    let deadline = tokio::time::Instant::now() + timeout;
    let mut buf = [0u8; FIRST_BYTES];
    loop {
        match tokio::time::timeout_at(deadline, stream.peek(&mut buf)).await {
            Ok(Ok(n)) if n >= FIRST_BYTES => return true,
            // closed, failed, or silent past the deadline
            Ok(Ok(0) | Err(_)) | Err(_) => return false,
            // part of them: peek returns at once while they are there, so wait a little
            Ok(Ok(_)) => {
                if tokio::time::Instant::now() >= deadline {
                    return false;
                }
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio_stream::StreamExt;

    #[tokio::test]
    async fn only_connections_that_speak_in_time_reach_the_server() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("binds");
        let addr = listener.local_addr().expect("address");
        let mut incoming = spoken(listener, Duration::from_millis(500));
        let mut silent = TcpStream::connect(addr).await.expect("connects");
        let mut slow = TcpStream::connect(addr).await.expect("connects");
        slow.write_all(b"PRI * HTTP/2.0").await.expect("part of it");
        let mut speaking = TcpStream::connect(addr).await.expect("connects");
        speaking
            .write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n")
            .await
            .expect("the preface");
        let arrived = tokio::time::timeout(Duration::from_secs(5), incoming.next())
            .await
            .expect("in time")
            .expect("a connection")
            .expect("accepted");
        assert_eq!(
            arrived.peer_addr().expect("peer"),
            speaking.local_addr().expect("local")
        );
        // the silent one and the one that stopped half-way are closed by the deadline
        for stream in [&mut silent, &mut slow] {
            let mut byte = [0u8; 1];
            let read = tokio::time::timeout(Duration::from_secs(5), stream.read(&mut byte))
                .await
                .expect("closed in time");
            assert!(matches!(read, Ok(0) | Err(_)), "{read:?}");
        }
        assert!(
            tokio::time::timeout(Duration::from_millis(200), incoming.next())
                .await
                .is_err(),
            "nothing else reached the server"
        );
    }
}
