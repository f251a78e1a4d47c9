//! Sending a batch's pixels to the displays that own its tiles: one QUIC stream per (frame,
//! batch, display). A tile is reported done only once its display has acknowledged its
//! stream, so tiles lost with a display connection are never counted as done.

use std::collections::BTreeMap;
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

/// How a batch's delivery ended: the tiles that reached their displays, and the displays that
/// could not be reached. Tiles of an unreachable display are not reported done, so the master
/// still holds them against this node: it copies them to another, or settles them once it
/// knows the display is gone.
pub struct Delivery {
    pub frame: FrameId,
    pub delivered: Vec<TileId>,
    /// The tiles of the unreachable displays.
    pub undelivered: Vec<TileId>,
    pub lost: Vec<(DisplayId, String)>,
}

pub fn send_pixels(
    displays: &BTreeMap<DisplayId, quinn::Connection>,
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
    let mut lost = Vec::new();
    let mut undelivered = Vec::new();
    for (display, indices) in by_display {
        let ids: Vec<TileId> = indices.iter().map(|&i| tiles[i]).collect();
        let Some(conn) = displays.get(&display).cloned() else {
            lost.push((display, "no connection to it".to_string()));
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
            (display, ids, sent.await)
        });
    }
    tokio::spawn(async move {
        let mut delivered = Vec::new();
        while let Some(joined) = sends.join_next().await {
            match joined {
                Ok((_, ids, Ok(()))) => delivered.extend(ids),
                Ok((display, ids, Err(e))) => {
                    lost.push((display, format!("{e:#}")));
                    undelivered.extend(ids);
                }
                // A send task cannot panic short of a bug; its tiles stay with the master.
                Err(e) => lost.push((DisplayId(u32::MAX), format!("the send task failed: {e}"))),
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
