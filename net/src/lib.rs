//! Serving and following the JSAE-RL services over gRPC.
//!
//! Layout: `serve` (serving with TCP_NODELAY, keep-alive and limits, reflection, shutdown
//! signals, a service's `main`, backoff, watch streams; its items are re-exported at the
//! root), `accept` (only connections that speak in time reach a server, and how many may
//! be open), `streams` (open streams and calls capped in all and per connection), `health`
//! (`grpc.health.v1` with capped watches), `security` (the token and TLS), `client`
//! (following snapshot streams with reconnection) and `logging` (text or JSON lines).

#![forbid(unsafe_code)]

pub mod accept;
pub mod client;
mod health;
pub mod logging;
pub mod security;
mod serve;
pub mod streams;

pub use serve::*;
