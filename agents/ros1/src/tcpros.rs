//! TCPROS wire format without message generation: connection headers
//! (length-prefixed `key=value` fields), length-prefixed message frames, and
//! the subscriber side of a connection (requestTopic on the publisher's slave
//! API, then the header handshake). Headers are bounded by
//! [`MAX_TCPROS_HEADER`] and frames by [`MAX_FRAME`] before anything is
//! allocated.

use std::collections::BTreeMap;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::http;
use crate::limits::{MAX_FRAME, MAX_TCPROS_HEADER};
use crate::xmlrpc::Value;

/// A connection header.
pub type Header = BTreeMap<String, String>;

/// Errors of TCPROS connections.
#[derive(Debug, thiserror::Error)]
pub enum TcprosError {
    #[error("tcpros io with {peer}")]
    Io {
        peer: String,
        #[source]
        source: std::io::Error,
    },
    #[error("requestTopic {topic} at {api}")]
    Request {
        api: String,
        topic: String,
        #[source]
        source: http::HttpError,
    },
    #[error("publisher {api} refused topic {topic}: {reason}")]
    Refused {
        api: String,
        topic: String,
        reason: String,
    },
    #[error("bad tcpros header or frame from {peer}: {what}")]
    Protocol { peer: String, what: String },
}

/// Encodes a header: u32 total length, then u32-length-prefixed fields.
pub fn encode_header(h: &Header) -> Vec<u8> {
    let mut body = Vec::new();
    for (k, v) in h {
        let f = format!("{k}={v}");
        body.extend_from_slice(&u32::try_from(f.len()).unwrap_or(u32::MAX).to_le_bytes());
        body.extend_from_slice(f.as_bytes());
    }
    let mut out = u32::try_from(body.len())
        .unwrap_or(u32::MAX)
        .to_le_bytes()
        .to_vec();
    out.extend(body);
    out
}

/// Decodes header fields (without the leading total length).
pub fn decode_header(mut b: &[u8]) -> Result<Header, String> {
    let mut h = Header::new();
    while !b.is_empty() {
        if b.len() < 4 {
            return Err("truncated field length".into());
        }
        let n = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
        b = &b[4..];
        if n > b.len() {
            return Err(format!("field length {n} beyond header"));
        }
        let f = String::from_utf8_lossy(&b[..n]);
        let (k, v) = f
            .split_once('=')
            .ok_or_else(|| format!("field without '=': {f:?}"))?;
        h.insert(k.to_string(), v.to_string());
        b = &b[n..];
    }
    Ok(h)
}

/// Reads one u32-length-prefixed message frame.
pub async fn read_block<R: AsyncRead + Unpin>(
    r: &mut R,
    peer: &str,
) -> Result<Vec<u8>, TcprosError> {
    read_limited(r, peer, MAX_FRAME, "frame").await
}

/// Reads one u32-length-prefixed block of at most `max` bytes; a larger
/// length prefix is refused before reading or allocating the block.
async fn read_limited<R: AsyncRead + Unpin>(
    r: &mut R,
    peer: &str,
    max: usize,
    what: &str,
) -> Result<Vec<u8>, TcprosError> {
    let io = |source| TcprosError::Io {
        peer: peer.into(),
        source,
    };
    let mut len = [0u8; 4];
    r.read_exact(&mut len).await.map_err(io)?;
    let n = u32::from_le_bytes(len) as usize;
    if n > max {
        return Err(TcprosError::Protocol {
            peer: peer.into(),
            what: format!("{what} length {n} is larger than the {max} byte limit"),
        });
    }
    let mut buf = vec![0u8; n];
    r.read_exact(&mut buf).await.map_err(io)?;
    Ok(buf)
}

/// Reads and decodes a connection header (at most [`MAX_TCPROS_HEADER`]).
pub async fn read_header<R: AsyncRead + Unpin>(
    r: &mut R,
    peer: &str,
) -> Result<Header, TcprosError> {
    let b = read_limited(r, peer, MAX_TCPROS_HEADER, "header").await?;
    decode_header(&b).map_err(|what| TcprosError::Protocol {
        peer: peer.into(),
        what,
    })
}

/// Writes one message frame (length prefix + payload).
pub async fn write_frame<W: AsyncWrite + Unpin>(
    w: &mut W,
    payload: &[u8],
    peer: &str,
) -> Result<(), TcprosError> {
    let io = |source| TcprosError::Io {
        peer: peer.into(),
        source,
    };
    let len = u32::try_from(payload.len()).map_err(|_| TcprosError::Protocol {
        peer: peer.into(),
        what: "frame too large".into(),
    })?;
    w.write_all(&len.to_le_bytes()).await.map_err(io)?;
    w.write_all(payload).await.map_err(io)
}

/// An open subscriber connection to one publisher.
#[derive(Debug)]
pub struct SubConn {
    pub stream: TcpStream,
    /// The publisher's reply header (type, md5sum, message_definition,
    /// callerid, latching).
    pub header: Header,
    pub peer: String,
}

/// Asks publisher `api` for `topic` and completes the TCPROS handshake as
/// `caller_id`, with md5sum `*` (accepts any type) and type `msg_type`.
pub async fn subscribe(
    api: &str,
    caller_id: &str,
    topic: &str,
    msg_type: &str,
    timeout: Duration,
) -> Result<SubConn, TcprosError> {
    let protos = Value::Array(vec![Value::Array(vec![Value::str("TCPROS")])]);
    let v = http::call(
        api,
        "requestTopic",
        &[Value::str(caller_id), Value::str(topic), protos],
        timeout,
    )
    .await
    .map_err(|source| TcprosError::Request {
        api: api.into(),
        topic: topic.into(),
        source,
    })?;
    let refused = |reason: String| TcprosError::Refused {
        api: api.into(),
        topic: topic.into(),
        reason,
    };
    let a = v.as_array().ok_or_else(|| refused("bad reply".into()))?;
    if a.first().and_then(Value::as_i64) != Some(1) {
        return Err(refused(
            a.get(1).and_then(Value::as_str).unwrap_or("").to_string(),
        ));
    }
    let proto = a
        .get(2)
        .and_then(Value::as_array)
        .ok_or_else(|| refused("no protocol".into()))?;
    let (Some("TCPROS"), Some(host), Some(port)) = (
        proto.first().and_then(Value::as_str),
        proto.get(1).and_then(Value::as_str),
        proto.get(2).and_then(Value::as_i64),
    ) else {
        return Err(refused(format!("unsupported protocol {proto:?}")));
    };
    let peer = format!("{host}:{port}");
    let io = |source| TcprosError::Io {
        peer: peer.clone(),
        source,
    };
    let port = u16::try_from(port).map_err(|_| refused(format!("bad port {port}")))?;
    let mut stream = tokio::time::timeout(timeout, TcpStream::connect((host, port)))
        .await
        .map_err(|_| io(std::io::ErrorKind::TimedOut.into()))?
        .map_err(io)?;
    let _ = stream.set_nodelay(true);
    let mut h = Header::new();
    h.insert("callerid".into(), caller_id.into());
    h.insert("topic".into(), topic.into());
    h.insert("md5sum".into(), "*".into());
    h.insert("type".into(), msg_type.into());
    h.insert("tcp_nodelay".into(), "1".into());
    stream.write_all(&encode_header(&h)).await.map_err(io)?;
    let header = tokio::time::timeout(timeout, read_header(&mut stream, &peer))
        .await
        .map_err(|_| io(std::io::ErrorKind::TimedOut.into()))??;
    if let Some(e) = header.get("error") {
        return Err(refused(e.clone()));
    }
    Ok(SubConn {
        stream,
        header,
        peer,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip() {
        let mut h = Header::new();
        h.insert("callerid".into(), "/a".into());
        h.insert("message_definition".into(), "string data\n# x=y".into());
        let b = encode_header(&h);
        assert_eq!(
            u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize,
            b.len() - 4
        );
        assert_eq!(decode_header(&b[4..]).unwrap(), h);
        assert!(decode_header(&[9, 0, 0, 0, b'a']).is_err());
        assert!(decode_header(&[1, 0, 0, 0, b'a']).is_err());
    }

    #[tokio::test]
    async fn frames_round_trip() {
        let (mut a, mut b) = tokio::io::duplex(1024);
        write_frame(&mut a, b"hello", "t").await.unwrap();
        assert_eq!(read_block(&mut b, "t").await.unwrap(), b"hello");
    }

    #[tokio::test]
    async fn headers_over_the_limit_are_refused_before_reading() {
        let (mut a, mut b) = tokio::io::duplex(64);
        let n = u32::try_from(MAX_TCPROS_HEADER + 1).unwrap();
        a.write_all(&n.to_le_bytes()).await.unwrap();
        let err = read_header(&mut b, "t").await.unwrap_err();
        assert!(
            err.to_string()
                .contains("header length 1048577 is larger than the 1048576 byte limit"),
            "{err}"
        );
    }

    mod props {
        use proptest::prelude::*;

        use super::*;

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(256))]

            #[test]
            fn headers_round_trip(h in prop::collection::btree_map("[^=]*", any::<String>(), 0..8)) {
                let b = encode_header(&h);
                prop_assert_eq!(decode_header(&b[4..]).unwrap(), h);
            }

            #[test]
            fn any_bytes_decode_or_err_without_panicking(b in prop::collection::vec(any::<u8>(), 0..512)) {
                if let Ok(h) = decode_header(&b) {
                    // Every byte was used by a field: re-encoding is no longer.
                    prop_assert!(encode_header(&h).len() <= b.len() + 4 || b.is_empty());
                }
            }

            #[test]
            fn read_header_accepts_exactly_what_fits(n in 0usize..(2 * MAX_TCPROS_HEADER)) {
                let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
                let r = rt.block_on(async {
                    let (mut a, mut b) = tokio::io::duplex(64);
                    a.write_all(&u32::try_from(n).unwrap().to_le_bytes()).await.unwrap();
                    drop(a);
                    read_header(&mut b, "t").await
                });
                match r {
                    // Within the limit the length is accepted and reading
                    // stops at the closed stream (or an empty header).
                    Err(TcprosError::Io { .. }) => prop_assert!(n > 0 && n <= MAX_TCPROS_HEADER),
                    Ok(h) => prop_assert!(n == 0 && h.is_empty()),
                    Err(e) => prop_assert!(n > MAX_TCPROS_HEADER, "{}", e),
                }
            }
        }
    }
}
