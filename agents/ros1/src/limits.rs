//! The data plane's limits on what network peers may send, in one place: the
//! XML-RPC servers (ROS master, parameter server, adaptor slave API) and the
//! TCPROS listener of the adaptors face every host that can reach them, and
//! a request over a limit is answered with an error while the server goes on
//! serving. The numbers are far above what ROS 1 nodes send (rosmaster sets
//! none) and far below what would exhaust the agent's memory or stack.

use std::time::Duration;

/// Largest XML-RPC request or response body, in bytes. rosparam's biggest
/// realistic upload (a robot description plus a few YAML files) is well under
/// 1 MiB; a body over the limit is answered with fault −32700 without reading
/// the rest. The XML-RPC client reads responses up to the same size (and
/// their heads up to hyper's read buffer).
pub const MAX_XMLRPC_BODY: usize = 16 << 20;

/// Deepest XML element nesting of an XML-RPC document. Every nested value
/// costs three elements (`<value><array><data>` or `<value><struct><member>`),
/// so this admits [`MAX_PARAM_DEPTH`] nested values plus the envelope; the
/// decoder recurses once per value, so this also bounds its stack.
pub const MAX_XML_DEPTH: usize = 128;

/// Most tags and texts in one XML-RPC document. The decoder holds every one
/// at once (about 70 bytes each), so a body of 16 MiB of `<a/>` would take
/// some 300 MB; this keeps one document under ~40 MB while admitting some
/// 100 000 values (a large `getParam /`, pretty-printed).
pub const MAX_XML_TOKENS: usize = 500_000;

/// Deepest parameter in the parameter server: the key's namespaces plus the
/// nesting of its value. setParam over it is refused, so that `getParam /`
/// always fits [`MAX_XML_DEPTH`] and the stored tree can be read back.
pub const MAX_PARAM_DEPTH: usize = 32;

/// How long an HTTP client may take to send a request's head, and how long a
/// kept-alive connection may stay idle before it is closed.
pub const HTTP_HEADER_TIMEOUT: Duration = Duration::from_secs(30);

/// How long an HTTP client may take to send a request's body.
pub const HTTP_BODY_TIMEOUT: Duration = Duration::from_secs(30);

/// Largest TCPROS connection header, in bytes. Headers carry the message
/// definition; the largest in common ROS packages is a few tens of KiB.
pub const MAX_TCPROS_HEADER: usize = 1 << 20;

/// How long a subscriber connecting to an adaptor may take to send its
/// TCPROS connection header.
pub const TCPROS_HEADER_TIMEOUT: Duration = Duration::from_secs(10);

/// Largest TCPROS message frame a meter or relay reads from a publisher (the
/// length prefix is a u32; images and point clouds stay well below this).
pub const MAX_FRAME: usize = 256 << 20;

/// The limits of one XML-RPC server; [`Default`] is the constants above.
/// Tests inject short timeouts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServeLimits {
    pub max_body: usize,
    pub header_timeout: Duration,
    pub body_timeout: Duration,
}

impl Default for ServeLimits {
    fn default() -> Self {
        Self {
            max_body: MAX_XMLRPC_BODY,
            header_timeout: HTTP_HEADER_TIMEOUT,
            body_timeout: HTTP_BODY_TIMEOUT,
        }
    }
}
