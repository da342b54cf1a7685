//! Accepting connections for a server: an accepted TCP connection reaches the server only
//! once it has sent its first [`FIRST_BYTES`] bytes (the HTTP/2 client preface; a TLS
//! ClientHello is longer), within [`FIRST_BYTES_TIMEOUT`]. A connection that stays silent is
//! closed then, and at most [`MAX_SILENT_CONNECTIONS`] wait at once (past that the one that
//! has waited longest is closed for the newcomer), so sockets that never speak can neither
//! pile up and take every file descriptor nor keep a real client out. All connections
//! together, silent or not, are at most [`connection_cap`]: at the cap a silent one is closed
//! for the newcomer, and where none is the newcomer is closed at once (logged), so the
//! process keeps descriptors for its own files and answers the clients it has.

use std::collections::VecDeque;
use std::pin::Pin;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, oneshot};
use tokio_stream::wrappers::ReceiverStream;

use crate::streams::CountedPlace;

/// How long an accepted connection has to send its first bytes.
pub const FIRST_BYTES_TIMEOUT: Duration = Duration::from_secs(10);
/// The bytes a connection must send before the server sees it: HTTP/2's client preface.
pub const FIRST_BYTES: usize = 24;
/// Most accepted connections that have not yet sent their first bytes.
pub const MAX_SILENT_CONNECTIONS: usize = 256;
/// Most connections a server holds at once, where the process may open enough files.
pub const MAX_CONNECTIONS: usize = 4096;
/// Descriptors kept for the process's own files (checkpoints, logs, the store) below its
/// limit of open files.
pub const RESERVED_DESCRIPTORS: usize = 64;

/// The most connections a server holds: [`MAX_CONNECTIONS`], or fewer where the process's
/// limit of open files (`ulimit -n`) leaves less beside [`RESERVED_DESCRIPTORS`].
pub fn connection_cap() -> usize {
    let files = rustix::process::getrlimit(rustix::process::Resource::Nofile)
        .current
        .map_or(usize::MAX, |n| usize::try_from(n).unwrap_or(usize::MAX));
    MAX_CONNECTIONS.min(files.saturating_sub(RESERVED_DESCRIPTORS).max(16))
}

/// Connections not yet spoken, oldest first: a number and what closes it.
type Silent = VecDeque<(u64, oneshot::Sender<()>)>;

/// An accepted connection, counted among the server's connections while it lives.
#[derive(Debug)]
pub struct Connection {
    stream: TcpStream,
    _counted: CountedPlace,
}

impl AsyncRead for Connection {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_read(cx, buf)
    }
}

impl AsyncWrite for Connection {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

impl tonic::transport::server::Connected for Connection {
    type ConnectInfo = tonic::transport::server::TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.stream.connect_info()
    }
}

impl Connection {
    /// The peer's address.
    pub fn peer_addr(&self) -> std::io::Result<std::net::SocketAddr> {
        self.stream.peer_addr()
    }
}

/// The connections of `listener` that spoke within `timeout` (TCP_NODELAY on), at most
/// [`connection_cap`] at once, for `serve_with_incoming`. The listener is dropped when the
/// stream is.
pub fn spoken(
    listener: TcpListener,
    timeout: Duration,
) -> ReceiverStream<std::io::Result<Connection>> {
    spoken_capped(listener, timeout, connection_cap())
}

fn spoken_capped(
    listener: TcpListener,
    timeout: Duration,
    cap: usize,
) -> ReceiverStream<std::io::Result<Connection>> {
    let (tx, rx) = mpsc::channel(64);
    // the connections still silent, oldest first, each with what closes it
    let silent: Arc<Mutex<Silent>> = Arc::default();
    let live = Arc::new(AtomicUsize::new(0));
    tokio::spawn(async move {
        let mut refused_logged: Option<tokio::time::Instant> = None;
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
                let full = live.load(Ordering::SeqCst) >= cap;
                if (waiting.len() >= MAX_SILENT_CONNECTIONS || full)
                    && let Some((_, oldest)) = waiting.pop_front()
                {
                    let _ = oldest.send(());
                } else if full {
                    // every connection held has spoken: the newcomer waits for none of them
                    if refused_logged.is_none_or(|at| at.elapsed() > Duration::from_secs(10)) {
                        tracing::warn!(
                            "{cap} connections are open, the most this process holds \
                             (accept::connection_cap): new ones are closed"
                        );
                        refused_logged = Some(tokio::time::Instant::now());
                    }
                    continue;
                }
                waiting.push_back((n, close));
            }
            let (counted, _) = CountedPlace::take(&live);
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
                    let connection = Connection {
                        stream,
                        _counted: counted,
                    };
                    let _ = tx.send(Ok(connection)).await;
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

    async fn speak(addr: std::net::SocketAddr) -> TcpStream {
        let mut s = TcpStream::connect(addr).await.expect("connects");
        s.write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n")
            .await
            .expect("the preface");
        s
    }

    async fn closed(stream: &mut TcpStream) -> bool {
        let mut byte = [0u8; 1];
        let read = tokio::time::timeout(Duration::from_secs(2), stream.read(&mut byte)).await;
        matches!(read, Ok(Ok(0) | Err(_)))
    }

    #[tokio::test]
    async fn at_the_cap_a_silent_connection_makes_room_and_else_the_newcomer_is_closed() {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("binds");
        let addr = listener.local_addr().expect("address");
        let mut incoming = spoken_capped(listener, Duration::from_secs(30), 2);
        let mut held = Vec::new();
        let _first = speak(addr).await;
        held.push(incoming.next().await.expect("first").expect("accepted"));
        let mut silent = TcpStream::connect(addr).await.expect("connects");
        tokio::time::sleep(Duration::from_millis(200)).await;
        // the cap is reached: the silent one is closed for a speaking newcomer
        let _second = speak(addr).await;
        assert!(closed(&mut silent).await, "the silent connection made room");
        held.push(incoming.next().await.expect("second").expect("accepted"));
        // two spoken connections held: a third is closed at once
        let mut third = speak(addr).await;
        assert!(
            closed(&mut third).await,
            "the newcomer past the cap is closed"
        );
        // one ends: there is room again
        held.pop();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let _fourth = speak(addr).await;
        let arrived = tokio::time::timeout(Duration::from_secs(5), incoming.next()).await;
        assert!(
            matches!(arrived, Ok(Some(Ok(_)))),
            "room again once one closed"
        );
    }

    #[test]
    fn the_cap_leaves_descriptors_for_the_process_own_files() {
        let cap = connection_cap();
        assert!((16..=MAX_CONNECTIONS).contains(&cap), "{cap}");
    }
}
