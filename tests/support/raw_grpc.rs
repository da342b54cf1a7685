//! Calls with bytes that need not be a message: a codec that sends what it is given and
//! reads answers as bytes, for the decoding and fuzz tests.

use std::time::Duration;

use bytes::{Buf, BufMut};
use tonic::Status;
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};
use tonic::codegen::http::uri::PathAndQuery;

/// Sends and receives raw bytes.
#[derive(Debug, Clone, Copy, Default)]
pub struct RawCodec;

/// The bytes as they are.
#[derive(Debug, Clone, Copy, Default)]
pub struct RawEncoder;

/// The answer's bytes.
#[derive(Debug, Clone, Copy, Default)]
pub struct RawDecoder;

impl Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawEncoder;
    type Decoder = RawDecoder;

    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }

    fn decoder(&mut self) -> RawDecoder {
        RawDecoder
    }
}

impl Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = Status;

    fn encode(&mut self, item: Vec<u8>, dst: &mut EncodeBuf<'_>) -> Result<(), Status> {
        dst.put_slice(&item);
        Ok(())
    }
}

impl Decoder for RawDecoder {
    type Item = Vec<u8>;
    type Error = Status;

    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<Vec<u8>>, Status> {
        let bytes = src.copy_to_bytes(src.remaining());
        Ok(Some(bytes.to_vec()))
    }
}

/// A raw client over `channel` (any tonic transport).
pub type RawClient<T> = tonic::client::Grpc<T>;

/// How an RPC is called.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// One message in, one out.
    Unary,
    /// Many in, one out.
    ClientStream,
    /// One in, a stream out (read for at most one message, then dropped).
    ServerStream,
}

/// Calls `path` (`/package.Service/Method`) with `messages` (only the first for a unary or
/// server-streaming call); the status code it ended with (`Ok` for an answer), within
/// `timeout`.
pub async fn call<T>(
    client: &mut RawClient<T>,
    path: &'static str,
    shape: Shape,
    messages: Vec<Vec<u8>>,
    timeout: Duration,
) -> Result<tonic::Code, tokio::time::error::Elapsed>
where
    T: tonic::client::GrpcService<tonic::body::Body> + Clone + Send + 'static,
    T::ResponseBody: tonic::codegen::Body<Data = bytes::Bytes> + Send + 'static,
    <T::ResponseBody as tonic::codegen::Body>::Error: Into<tonic::codegen::StdError> + Send,
    T::Error: Into<tonic::codegen::StdError>,
    T::Future: Send,
{
    let path = PathAndQuery::from_static(path);
    let first = messages.first().cloned().unwrap_or_default();
    tokio::time::timeout(timeout, async move {
        if client.ready().await.is_err() {
            return tonic::Code::Unavailable;
        }
        let code = |r: Result<tonic::Code, Status>| r.unwrap_or_else(|s| s.code());
        match shape {
            Shape::Unary => code(
                client
                    .unary(tonic::Request::new(first), path, RawCodec)
                    .await
                    .map(|_| tonic::Code::Ok),
            ),
            Shape::ClientStream => code(
                client
                    .client_streaming(
                        tonic::Request::new(tokio_stream::iter(messages)),
                        path,
                        RawCodec,
                    )
                    .await
                    .map(|_| tonic::Code::Ok),
            ),
            Shape::ServerStream => {
                let answer = client
                    .server_streaming(tonic::Request::new(first), path, RawCodec)
                    .await;
                match answer {
                    Err(s) => s.code(),
                    Ok(stream) => {
                        let mut stream = stream.into_inner();
                        // one message at most, then the stream is dropped mid-way
                        let next =
                            tokio::time::timeout(Duration::from_millis(20), stream.message()).await;
                        match next {
                            Ok(Err(s)) => s.code(),
                            _ => tonic::Code::Ok,
                        }
                    }
                }
            }
        }
    })
    .await
}
