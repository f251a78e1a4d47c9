//! Receiving pixel streams from render nodes. Each stream is checked against the wall before
//! any pixel is read: a bad header, a compression other than the session's, a tile of another
//! display, a wrong length or a tile that does not unpack to its pixels closes that render
//! node's connection with a log line, and the display goes on.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use tessera_model::state::StateId;
use tessera_model::wall::{DisplayId, TileGrid, TileId};
use tessera_protocol::pixels::{
    BatchSource, Compression, StreamHeader, TileHeader, STREAM_HEADER_LEN, TILE_HEADER_LEN,
};
use tessera_protocol::FrameId;
use tokio::sync::mpsc;

pub struct IncomingTile {
    pub frame: FrameId,
    pub state: StateId,
    /// Who rendered it, and how long a tile of its batch took.
    pub source: BatchSource,
    pub tile: TileId,
    pub rgb: Vec<u8>,
    pub conn: quinn::Connection,
}

/// Counters shared by all receiving tasks.
#[derive(Default)]
pub struct Intake {
    pub stream_bytes: AtomicU64,
    pub pixel_bytes: AtomicU64,
    /// The render-node connections open now.
    pub connections: Mutex<Vec<quinn::Connection>>,
    /// UDP bytes of the connections that closed: a closed connection is let go (a handle
    /// keeps all its state, about a megabyte, alive; a wall whose render nodes come and go
    /// grew by that much per node).
    pub closed_wire_bytes: AtomicU64,
}

impl Intake {
    /// UDP bytes received on every render-node connection so far (closed ones included).
    pub fn wire_bytes(&self) -> u64 {
        let conns = self.connections.lock().expect("intake lock");
        let open: u64 = conns.iter().map(|c| c.stats().udp_rx.bytes).sum();
        open + self.closed_wire_bytes.load(Ordering::Relaxed)
    }

    /// `conn` ended: keep its byte count, drop the connection.
    fn closed(&self, conn: &quinn::Connection) {
        let mut conns = self.connections.lock().expect("intake lock");
        conns.retain(|c| c.stable_id() != conn.stable_id());
        self.closed_wire_bytes
            .fetch_add(conn.stats().udp_rx.bytes, Ordering::Relaxed);
    }
}

/// Accepts render-node connections until the endpoint closes.
pub async fn accept_render_nodes(
    endpoint: quinn::Endpoint,
    grid: Arc<TileGrid>,
    me: DisplayId,
    compression: Compression,
    intake: Arc<Intake>,
    tiles: mpsc::Sender<IncomingTile>,
) {
    while let Some(incoming) = endpoint.accept().await {
        let (grid, intake, tiles) = (grid.clone(), intake.clone(), tiles.clone());
        tokio::spawn(async move {
            let remote = incoming.remote_address();
            let conn = match incoming.await {
                Ok(c) => c,
                Err(e) => {
                    tracing::warn!("display {}: refused a connection from {remote}: {e}", me.0);
                    return;
                }
            };
            intake
                .connections
                .lock()
                .expect("intake lock")
                .push(conn.clone());
            while let Ok(stream) = conn.accept_uni().await {
                let (grid, intake, tiles, conn) =
                    (grid.clone(), intake.clone(), tiles.clone(), conn.clone());
                tokio::spawn(async move {
                    if let Err(e) =
                        read_stream(stream, &grid, me, compression, &intake, &tiles, &conn).await
                    {
                        tracing::error!(
                            "display {}: closing the connection from {remote}: {e:#}",
                            me.0
                        );
                        conn.close(3u32.into(), b"bad pixel stream");
                    }
                });
            }
            intake.closed(&conn);
        });
    }
}

async fn read_stream(
    mut stream: quinn::RecvStream,
    grid: &TileGrid,
    me: DisplayId,
    compression: Compression,
    intake: &Intake,
    tiles: &mpsc::Sender<IncomingTile>,
    conn: &quinn::Connection,
) -> anyhow::Result<()> {
    let mut header = [0u8; STREAM_HEADER_LEN];
    stream.read_exact(&mut header).await?;
    let header = StreamHeader::decode(&header, grid.display_tiles(me).len() as u32)?;
    if header.compression != compression {
        anyhow::bail!(
            "pixel stream packed as {:?}, but this run's compression is {compression:?}",
            header.compression
        );
    }
    intake
        .stream_bytes
        .fetch_add(STREAM_HEADER_LEN as u64, Ordering::Relaxed);
    for _ in 0..header.tile_count {
        let mut th = [0u8; TILE_HEADER_LEN];
        stream.read_exact(&mut th).await?;
        let th = TileHeader::decode(&th);
        let tile = grid
            .tile(th.tile)
            .filter(|t| t.display == me)
            .ok_or_else(|| {
                anyhow::anyhow!("tile {} does not belong to display {}", th.tile.0, me.0)
            })?;
        let expected = tile.pixel_count() * header.format.bytes_per_pixel();
        compression.check_tile_len(&th, expected)?;
        let mut payload = vec![0u8; th.byte_len as usize];
        stream.read_exact(&mut payload).await?;
        intake
            .stream_bytes
            .fetch_add((TILE_HEADER_LEN + payload.len()) as u64, Ordering::Relaxed);
        let rgb = compression.decode_tile(th.tile, payload, expected)?;
        intake
            .pixel_bytes
            .fetch_add(expected as u64, Ordering::Relaxed);
        let incoming = IncomingTile {
            frame: header.frame,
            state: header.state,
            source: header.source,
            tile: th.tile,
            rgb,
            conn: conn.clone(),
        };
        if tiles.send(incoming).await.is_err() {
            return Ok(());
        }
    }
    // Anything after the announced tiles is a protocol violation.
    let mut extra = [0u8; 1];
    if stream.read(&mut extra).await?.is_some_and(|n| n > 0) {
        anyhow::bail!(
            "pixel stream carries bytes after its {} tiles",
            header.tile_count
        );
    }
    Ok(())
}
