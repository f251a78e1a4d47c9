//! Sending a batch's pixels to the displays that own its tiles: one QUIC stream per (frame,
//! batch, display). A tile is reported done only once its display has acknowledged its
//! stream, so tiles lost with a display connection are never counted as done.

use std::collections::BTreeMap;
use tessera_core::node::render::LinkId;
use tessera_model::state::StateId;
use tessera_model::wall::{DisplayId, TileGrid, TileId};
use tessera_protocol::pixels::{encode_batch, BatchSource, Compression};
use tessera_protocol::FrameId;
use tokio::sync::mpsc;

/// A rendered batch of one frame's tiles, each tile's payload packed for the wire.
pub struct Batch {
    pub frame: FrameId,
    pub state: StateId,
    pub source: BatchSource,
    pub tiles: Vec<TileId>,
    pub payloads: Vec<Vec<u8>>,
}

/// The connection to a display, and which of the display's links it is: a failure on it is
/// reported with the link, so that one on a display's old connection is never taken for one on
/// its new.
#[derive(Clone)]
pub struct DisplayConn {
    pub link: LinkId,
    pub conn: quinn::Connection,
}

/// How a batch's delivery ended: the tiles that reached their displays, and the links that
/// failed. Tiles of an unreachable display are not reported done, so the master
/// still holds them against this node: it copies them to another, or settles them once it
/// knows the display is gone.
pub struct Delivery {
    pub frame: FrameId,
    pub delivered: Vec<TileId>,
    /// The tiles of the unreachable displays.
    pub undelivered: Vec<TileId>,
    pub lost: Vec<(DisplayId, LinkId, String)>,
}

pub fn send_pixels(
    displays: &BTreeMap<DisplayId, DisplayConn>,
    grid: &TileGrid,
    compression: Compression,
    batch: Batch,
    done: mpsc::UnboundedSender<Delivery>,
) {
    let Batch {
        frame,
        state,
        source,
        tiles,
        payloads,
    } = batch;
    let mut by_display: BTreeMap<DisplayId, Vec<usize>> = BTreeMap::new();
    for (i, t) in tiles.iter().enumerate() {
        let tile = grid
            .tile(*t)
            .expect("the worker checked every assigned tile");
        by_display.entry(tile.display).or_default().push(i);
    }
    // One task per display, all at once: a display that stalls holds back only its own tiles.
    let mut sends = tokio::task::JoinSet::new();
    let mut lost: Vec<(DisplayId, LinkId, String)> = Vec::new();
    let mut undelivered = Vec::new();
    for (display, indices) in by_display {
        let ids: Vec<TileId> = indices.iter().map(|&i| tiles[i]).collect();
        // Without a connection the session has forgotten the display already: nothing to
        // report lost, the tiles just go back.
        let Some(DisplayConn { link, conn }) = displays.get(&display).cloned() else {
            undelivered.extend(ids);
            continue;
        };
        let bytes = encode_batch(
            (frame, state),
            source,
            compression,
            indices.iter().map(|&i| (tiles[i], payloads[i].as_slice())),
        );
        sends.spawn(async move {
            let sent = async {
                let mut stream = conn.open_uni().await?;
                stream.write_all(&bytes).await?;
                stream.finish()?;
                stream.stopped().await?;
                anyhow::Ok(())
            };
            (display, link, ids, sent.await)
        });
    }
    tokio::spawn(async move {
        let mut delivered = Vec::new();
        while let Some(joined) = sends.join_next().await {
            match joined {
                Ok((_, _, ids, Ok(()))) => delivered.extend(ids),
                Ok((display, link, ids, Err(e))) => {
                    lost.push((display, link, format!("{e:#}")));
                    undelivered.extend(ids);
                }
                // A send task cannot panic short of a bug; its tiles stay with the master.
                Err(e) => tracing::warn!("a pixel send task failed: {e}"),
            }
        }
        delivered.sort();
        undelivered.sort();
        let _ = done.send(Delivery {
            frame,
            delivered,
            undelivered,
            lost,
        });
    });
}
