//! Every message on the wire.
//!
//! Control messages are postcard-encoded enums in length-prefixed frames ([`codec`]) on one
//! bidirectional QUIC stream per node–master connection. Pixels travel separately, render node to
//! display node, as RGB8 (raw or LZ4 per tile) with one small header per tile ([`pixels`]), one
//! unidirectional stream per (frame, batch of tiles, display). Every decoder has a size limit and returns an error on
//! malformed input; semantic checks (is this tile mine? is this frame in flight?) are done by the
//! state machine that consumes the message.

pub mod codec;
pub mod pixels;

use crate::render::{Camera, RenderParams};
use crate::scene::SceneSpec;
use crate::wall::{DisplayId, TileId, WallLayout};
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;

/// Bumped on any incompatible change of a message or of the pixel stream format.
pub const PROTOCOL_VERSION: u32 = 3;

/// ALPN of Tessera's QUIC connections; a peer speaking anything else is refused by TLS.
pub const ALPN: &[u8] = b"tessera/1";

/// A frame number; frames are numbered from 0 in the order they are presented.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct FrameId(pub u64);

/// Identifies a render node within one run, assigned by the master in join order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct RenderNodeId(pub u32);

/// What a connecting node is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Role {
    Render {
        /// Threads the node renders with.
        cores: u32,
    },
    Display {
        display: DisplayId,
        /// Where render nodes reach this display. An unspecified IP (0.0.0.0 / ::) means
        /// "the address the master sees me connect from".
        pixel_addr: SocketAddr,
    },
}

/// The first message on every control stream.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hello {
    pub version: u32,
    pub role: Role,
    /// Host name, for log lines and reports.
    pub host: String,
}

/// Where a display node accepts pixels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DisplayEndpoint {
    pub display: DisplayId,
    pub addr: SocketAddr,
}

/// Everything a node needs to take part in a run, sent once after the handshake.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Session {
    pub wall: WallLayout,
    pub scene: SceneSpec,
    /// Content hash of the scene as the master loaded it; a render node that loads different
    /// bytes would render different pixels, so it refuses to join.
    pub scene_hash: [u8; 32],
    pub displays: Vec<DisplayEndpoint>,
    /// Frame whose pixels the displays save as PNG, if any.
    pub save_frame: Option<FrameId>,
    /// How render nodes pack tiles' pixels; displays refuse streams packed otherwise.
    pub compression: pixels::Compression,
}

/// Broadcast at the frame barrier: the state every node renders frame `frame` with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameStart {
    pub frame: FrameId,
    pub camera: Camera,
    pub params: RenderParams,
}

/// Tiles `start..end` (ids). Assignments are mostly contiguous, so ranges keep them small.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileRange {
    pub start: u32,
    pub end: u32,
}

impl TileRange {
    pub fn tiles(self) -> impl Iterator<Item = TileId> {
        (self.start..self.end).map(TileId)
    }

    pub fn len(self) -> usize {
        self.end.saturating_sub(self.start) as usize
    }

    pub fn is_empty(self) -> bool {
        self.len() == 0
    }
}

/// Compresses a sorted-or-not list of tile ids into ranges of consecutive ids.
pub fn to_ranges(tiles: impl IntoIterator<Item = TileId>) -> Vec<TileRange> {
    let mut ranges: Vec<TileRange> = Vec::new();
    for TileId(t) in tiles {
        match ranges.last_mut() {
            Some(r) if r.end == t => r.end += 1,
            _ => ranges.push(TileRange {
                start: t,
                end: t + 1,
            }),
        }
    }
    ranges
}

/// Master → node.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ToNode {
    Welcome {
        node: RenderNodeId,
        session: Session,
    },
    Refused {
        reason: String,
    },
    FrameStart(FrameStart),
    /// Tiles of `frame` for a render node to render; empty means "nothing left for now".
    Assign {
        frame: FrameId,
        tiles: Vec<TileRange>,
    },
    /// The swap barrier: every display shows `frame` now.
    Present {
        frame: FrameId,
    },
    /// The swap barrier with a deadline: show `frame` when this display's clock (ns since the
    /// Unix epoch) reads `clock_ns`, or at once if that has passed. Every display waking at
    /// the same instant, rather than whenever the message arrives, is what keeps them in step.
    PresentAt {
        frame: FrameId,
        clock_ns: u64,
    },
    /// The run is over: send your stats and close.
    Shutdown,
    /// Clock probe: a display answers at once with [`FromNode::Pong`], so the master can map
    /// the display's clock onto its own (NTP-style, keeping the fastest round trip).
    Ping {
        seq: u32,
    },
}

/// Node → master.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum FromNode {
    Hello(Hello),
    /// Scene loaded, displays reached: the node can take frames.
    Ready,
    /// These tiles reached their displays. With `want_more` the node asks for another batch.
    TilesDone {
        frame: FrameId,
        tiles: Vec<TileRange>,
        want_more: bool,
    },
    /// A display has every tile of `frame`.
    FrameComplete {
        frame: FrameId,
    },
    /// A display showed `frame`, at `clock_ns` on its own clock (ns since the Unix epoch).
    Presented {
        frame: FrameId,
        clock_ns: u64,
    },
    /// Answer to [`ToNode::Ping`]: the display's clock when it answered.
    Pong {
        seq: u32,
        clock_ns: u64,
    },
    Stats(NodeStats),
    /// The node cannot go on; the master logs this and treats the node as gone.
    Failed {
        message: String,
    },
}

/// Measured by a node, reported at shutdown.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum NodeStats {
    Render(RenderStats),
    Display(DisplayStats),
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RenderStats {
    pub tiles: u64,
    pub rays: u64,
    /// Seconds spent rendering (wall clock of render calls).
    pub busy_s: f64,
    /// Seconds from the first frame start to shutdown.
    pub elapsed_s: f64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DisplayStats {
    pub pixels_owned: u64,
    /// Pixel bytes received, as unpacked (3 per pixel, whatever the compression; tile headers
    /// excluded).
    pub pixel_bytes_received: u64,
    /// UDP payload bytes received on render-node connections, as quinn counts them: every
    /// datagram's QUIC packet headers, AEAD tags, frames (handshake, ACKs, retransmissions
    /// included), but not the IP and UDP headers.
    pub wire_bytes_received: u64,
    /// Application bytes of pixel streams as sent (stream and tile headers included, tiles
    /// compressed if the run compresses).
    pub stream_bytes_received: u64,
    pub frames_presented: u64,
    pub duplicate_tiles: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_merge_consecutive_ids() {
        let r = to_ranges([1, 2, 3, 7, 8, 10].map(TileId));
        assert_eq!(
            r,
            vec![
                TileRange { start: 1, end: 4 },
                TileRange { start: 7, end: 9 },
                TileRange { start: 10, end: 11 }
            ]
        );
        let back: Vec<u32> = r.iter().flat_map(|r| r.tiles()).map(|t| t.0).collect();
        assert_eq!(back, vec![1, 2, 3, 7, 8, 10]);
    }
}
