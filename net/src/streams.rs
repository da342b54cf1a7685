//! Limits on what clients hold open: calls per connection ([`PerConnection`], keyed by the
//! peer's address, so one client cannot take every slot of a limited call) and, for the
//! long-lived server streams (`WatchPolicy`, `WatchEmbedding`, `Health.Watch`), a cap on
//! how many are open at once ([`StreamLimit`]). A stream holds little while it is open (the
//! snapshots it sends are shared and cut into chunks as they go, `wire::SnapshotChunks`), so
//! the caps bound a service's memory whatever its clients do, and a call past one is
//! RESOURCE_EXHAUSTED before anything is sent.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use jsae_wire::RpcError;

/// Most `WatchPolicy` or `WatchEmbedding` streams a service has open at once (every actor
/// and follower holds one).
pub const MAX_WATCH_STREAMS: usize = 256;
/// Most of them one connection may hold.
pub const MAX_WATCHES_PER_CONNECTION: usize = 8;
/// Most `grpc.health.v1.Health/Watch` streams a service has open at once (`Check`, which
/// probes use, is not limited).
pub const MAX_HEALTH_WATCHES: usize = 32;
/// Most of them one connection may hold.
pub const MAX_HEALTH_WATCHES_PER_CONNECTION: usize = 2;

/// One place in a shared count, taken when made and given back when dropped.
#[derive(Debug)]
pub struct CountedPlace(Arc<AtomicUsize>);

impl CountedPlace {
    /// Takes a place in `count`; also gives the count before it.
    pub fn take(count: &Arc<AtomicUsize>) -> (Self, usize) {
        let before = count.fetch_add(1, Ordering::SeqCst);
        (Self(count.clone()), before)
    }
}

impl Drop for CountedPlace {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A limit and the name of its constant (which a refusal names).
#[derive(Debug, Clone, Copy)]
pub struct Cap {
    /// The most allowed.
    pub n: usize,
    /// The constant that sets it.
    pub name: &'static str,
}

/// Open calls counted per connection (its peer's address), at most `max` each.
#[derive(Debug, Clone)]
pub struct PerConnection {
    what: &'static str,
    max: Cap,
    open: Arc<Mutex<HashMap<Option<SocketAddr>, usize>>>,
}

impl PerConnection {
    /// At most `max` open `what` (a call's name, for the refusal) per connection.
    pub fn new(what: &'static str, max: Cap) -> Self {
        Self {
            what,
            max,
            open: Arc::default(),
        }
    }

    /// Counts a call of `peer` while the guard lives; RESOURCE_EXHAUSTED when its connection
    /// has `max` already.
    pub fn enter(&self, peer: Option<SocketAddr>) -> Result<ConnectionGuard, RpcError> {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        let n = open.entry(peer).or_default();
        if *n >= self.max.n {
            return Err(RpcError::ResourceExhausted(format!(
                "this connection has {} {} calls open, the most one connection may ({}): wait \
                 for one to end",
                self.max.n, self.what, self.max.name
            )));
        }
        *n += 1;
        Ok(ConnectionGuard {
            open: self.open.clone(),
            peer,
        })
    }

    /// Calls open on `peer`'s connection.
    pub fn count(&self, peer: Option<SocketAddr>) -> usize {
        let open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        open.get(&peer).copied().unwrap_or(0)
    }
}

/// One call counted against its connection while it lives.
#[derive(Debug)]
pub struct ConnectionGuard {
    open: Arc<Mutex<HashMap<Option<SocketAddr>, usize>>>,
    peer: Option<SocketAddr>,
}

impl Drop for ConnectionGuard {
    fn drop(&mut self) {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = open.get_mut(&self.peer) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.peer);
            }
        }
    }
}

/// A cap on open streams of one kind: `total` in all, `per_connection` on each connection.
#[derive(Debug, Clone)]
pub struct StreamLimit {
    total: Cap,
    open: Arc<AtomicUsize>,
    connections: PerConnection,
}

impl StreamLimit {
    /// At most `total` open `what` streams, `per_connection` of them on one connection.
    pub fn new(what: &'static str, total: Cap, per_connection: Cap) -> Self {
        Self {
            total,
            open: Arc::default(),
            connections: PerConnection::new(what, per_connection),
        }
    }

    /// The limit of `WatchPolicy` or `WatchEmbedding` streams.
    pub fn watches(what: &'static str) -> Self {
        Self::new(
            what,
            Cap {
                n: MAX_WATCH_STREAMS,
                name: "MAX_WATCH_STREAMS",
            },
            Cap {
                n: MAX_WATCHES_PER_CONNECTION,
                name: "MAX_WATCHES_PER_CONNECTION",
            },
        )
    }

    /// A stream of `peer`, counted while the permit lives; RESOURCE_EXHAUSTED when `total`
    /// are open or its connection holds `per_connection`.
    pub fn enter(&self, peer: Option<SocketAddr>) -> Result<StreamPermit, RpcError> {
        let connection = self.connections.enter(peer)?;
        let (place, before) = CountedPlace::take(&self.open);
        if before >= self.total.n {
            return Err(RpcError::ResourceExhausted(format!(
                "{} {} streams are open, the most this service holds ({}): try again later",
                self.total.n, self.connections.what, self.total.name
            )));
        }
        Ok(StreamPermit {
            _place: place,
            _connection: connection,
        })
    }

    /// Streams open now.
    pub fn open(&self) -> usize {
        self.open.load(Ordering::SeqCst)
    }
}

/// One open stream of a [`StreamLimit`]; dropping it (when the stream ends) frees its place.
#[derive(Debug)]
pub struct StreamPermit {
    _place: CountedPlace,
    _connection: ConnectionGuard,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn peer(port: u16) -> Option<SocketAddr> {
        Some(SocketAddr::from(([127, 0, 0, 1], port)))
    }

    #[test]
    fn streams_are_capped_in_all_and_per_connection_and_freed_when_dropped() {
        let limit = StreamLimit::new(
            "WatchPolicy",
            Cap { n: 3, name: "ALL" },
            Cap { n: 2, name: "EACH" },
        );
        let a1 = limit.enter(peer(1)).expect("first of a");
        let _a2 = limit.enter(peer(1)).expect("second of a");
        let e = limit.enter(peer(1)).expect_err("a third on one connection");
        assert!(e.to_string().contains("this connection"), "{e}");
        let _b1 = limit.enter(peer(2)).expect("another connection");
        let e = limit.enter(peer(3)).expect_err("past the total");
        assert!(e.to_string().contains("3 WatchPolicy streams"), "{e}");
        assert_eq!(limit.open(), 3);
        drop(a1);
        assert_eq!(limit.open(), 2);
        let _c1 = limit.enter(peer(3)).expect("a place is free again");
        // a refusal for the total leaves the connection's count as it was
        assert_eq!(limit.connections.count(peer(4)), 0);
        assert!(limit.enter(peer(4)).is_err());
        assert_eq!(limit.connections.count(peer(4)), 0);
    }
}
