//! The message every simnode sends: `std_msgs/UInt8MultiArray` (shipped by
//! Debian's python3-std-msgs, so rospy, `rostopic echo` and `rostopic hz`
//! decode it). The layout is empty; the data array carries a 16-byte header:
//! bytes 0..8 the publisher's sequence number (u64 LE), bytes 8..16 the
//! source stamp in nanoseconds since the Unix epoch (u64 LE) — the time the
//! originating sensor message was made, carried through callbacks so
//! consumers can measure end-to-end latency. Encoding and decoding are pure.

use std::time::{SystemTime, UNIX_EPOCH};

/// ROS type name.
pub const MSG_TYPE: &str = "std_msgs/UInt8MultiArray";
/// MD5 sum of the type (as `rosmsg md5 std_msgs/UInt8MultiArray`).
pub const MD5SUM: &str = "82373f1612381bb6ee473b5cd6f5d89c";
/// The full message definition sent in the TCPROS header.
pub const DEFINITION: &str = "MultiArrayLayout  layout
uint8[]           data

================================================================================
MSG: std_msgs/MultiArrayLayout
MultiArrayDimension[] dim
uint32 data_offset

================================================================================
MSG: std_msgs/MultiArrayDimension
string label
uint32 size
uint32 stride
";

/// What a simnode reads back from a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Meta {
    pub seq: u64,
    pub stamp_ns: u64,
    /// Length of the data array.
    pub data_len: usize,
}

/// Now, in nanoseconds since the Unix epoch.
pub fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// Serialises a message with a `data_len`-byte data array (at least 16).
pub fn encode(seq: u64, stamp_ns: u64, data_len: usize) -> Vec<u8> {
    let n = data_len.max(16);
    let len = u32::try_from(n).unwrap_or(u32::MAX);
    let mut b = vec![0u8; 12 + n];
    // layout.dim length (0) and layout.data_offset (0) stay zero.
    b[8..12].copy_from_slice(&len.to_le_bytes());
    b[12..20].copy_from_slice(&seq.to_le_bytes());
    b[20..28].copy_from_slice(&stamp_ns.to_le_bytes());
    b
}

fn u32_at(b: &[u8], at: usize) -> Option<usize> {
    let s = b.get(at..at + 4)?;
    Some(u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize)
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    let s: [u8; 8] = b.get(at..at + 8)?.try_into().ok()?;
    Some(u64::from_le_bytes(s))
}

/// Reads seq, stamp and data length from a serialised UInt8MultiArray
/// (any layout); `None` when it is not one or carries no 16-byte header.
pub fn decode(b: &[u8]) -> Option<Meta> {
    let dims = u32_at(b, 0)?;
    let mut at = 4usize;
    for _ in 0..dims.min(64) {
        let label = u32_at(b, at)?;
        at = at.checked_add(4 + label + 8)?;
    }
    if dims > 64 {
        return None;
    }
    at += 4; // data_offset
    let data_len = u32_at(b, at)?;
    at += 4;
    if b.len() != at + data_len || data_len < 16 {
        return None;
    }
    Some(Meta {
        seq: u64_at(b, at)?,
        stamp_ns: u64_at(b, at + 8)?,
        data_len,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_foreign_layouts() {
        let b = encode(7, 123_456_789, 100);
        assert_eq!(b.len(), 112);
        assert_eq!(
            decode(&b),
            Some(Meta {
                seq: 7,
                stamp_ns: 123_456_789,
                data_len: 100
            })
        );
        assert_eq!(encode(1, 2, 3).len(), 12 + 16);
        // One dimension labelled "h" before the data.
        let mut f = vec![1, 0, 0, 0, 1, 0, 0, 0, b'h', 2, 0, 0, 0, 2, 0, 0, 0];
        f.extend_from_slice(&encode(9, 10, 16)[4..]);
        assert_eq!(decode(&f).map(|m| (m.seq, m.stamp_ns)), Some((9, 10)));
        assert_eq!(decode(b"\x05\x00\x00\x00hello"), None);
        assert_eq!(decode(&b[..50]), None);
    }
}
