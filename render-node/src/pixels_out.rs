//! Sending a batch's pixels to the displays that own its tiles: one QUIC stream per (frame,
//! batch, display). The report goes back only once every display has acknowledged its
//! stream, so tiles lost with a display connection are never counted as done.

use std::collections::BTreeMap;
use tessera_wire::protocol::pixels::{encode_batch, BatchSource, Compression};
use tessera_wire::protocol::FrameId;
use tessera_wire::state::StateId;
use tessera_wire::wall::{DisplayId, TileGrid, TileId};
use tokio::sync::mpsc;

/// A rendered batch of one frame's tiles, each tile's payload packed for the wire.
pub struct Batch {
    pub frame: FrameId,
    pub state: StateId,
    pub source: BatchSource,
    pub tiles: Vec<TileId>,
    pub payloads: Vec<Vec<u8>>,
}

/// How a batch's delivery ended.
pub enum Delivery {
    /// Every display has its tiles of the batch.
    Delivered {
        frame: FrameId,
        tiles: Vec<TileId>,
    },
    Failed(String),
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
    let mut sends = Vec::new();
    for (display, indices) in by_display {
        let Some(conn) = displays.get(&display).cloned() else {
            let _ = done.send(Delivery::Failed(format!(
                "no connection to display {}",
                display.0
            )));
            return;
        };
        let bytes = encode_batch(
            (frame, state),
            source,
            compression,
            indices.iter().map(|&i| (tiles[i], payloads[i].as_slice())),
        );
        sends.push(async move {
            let mut stream = conn.open_uni().await?;
            stream.write_all(&bytes).await?;
            stream.finish()?;
            stream.stopped().await?;
            anyhow::Ok(())
        });
    }
    tokio::spawn(async move {
        for s in sends {
            if let Err(e) = s.await {
                let _ = done.send(Delivery::Failed(format!("{e:#}")));
                return;
            }
        }
        let _ = done.send(Delivery::Delivered { frame, tiles });
    });
}
