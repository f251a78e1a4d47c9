//! Answers other render nodes' requests for the blocks this node holds (its share and the top
//! of the tree), each request on a stream of its own. Only render nodes of the cluster are
//! answered: a connection whose certificate names another role is closed.

use std::sync::{Arc, RwLock};
use tessera_net::cluster::CertRole;
use tessera_net::framed::read_msg;
use tessera_protocol::dsm::{encode_block_header, BlockRequest, MAX_BLOCKS_PER_REQUEST};
use tessera_render::PreparedScene;

/// Serves `scene`'s local blocks on `endpoint` until the task is aborted or the endpoint
/// closes.
pub async fn serve(endpoint: quinn::Endpoint, scene: Arc<RwLock<PreparedScene>>) {
    while let Some(incoming) = endpoint.accept().await {
        let scene = scene.clone();
        tokio::spawn(async move {
            let remote = incoming.remote_address();
            let conn = match incoming.await {
                Ok(c) => c,
                Err(e) => {
                    tracing::warn!("refused a block connection from {remote}: {e}");
                    return;
                }
            };
            if !tessera_net::quic::peer_roles(&conn).contains(&CertRole::Render) {
                tracing::warn!(
                    "closing a block connection from {remote}: not a render node's certificate"
                );
                conn.close(6u32.into(), b"blocks are for render nodes");
                return;
            }
            while let Ok((send, recv)) = conn.accept_bi().await {
                let scene = scene.clone();
                tokio::spawn(async move {
                    if let Err(e) = answer(send, recv, &scene).await {
                        tracing::debug!("a block request from {remote} ended: {e:#}");
                    }
                });
            }
        });
    }
}

/// Answers one request: each block asked for, in order, with its header, and its bytes if
/// this node holds it.
async fn answer(
    mut send: quinn::SendStream,
    mut recv: quinn::RecvStream,
    scene: &RwLock<PreparedScene>,
) -> anyhow::Result<()> {
    let Some(request) = read_msg::<BlockRequest>(&mut recv).await? else {
        return Ok(());
    };
    if request.blocks.len() > MAX_BLOCKS_PER_REQUEST {
        anyhow::bail!("{} blocks in one request", request.blocks.len());
    }
    if request.ahead {
        // Streams of misses, which render threads wait for, go first.
        let _ = send.set_priority(-1);
    }
    for k in request.blocks {
        // Copied out, so the scene's lock is never held across a send.
        let bytes: Option<Vec<u8>> = {
            let scene = scene.read().unwrap_or_else(|e| e.into_inner());
            scene
                .shared
                .as_ref()
                .and_then(|tree| tree.local(k))
                .map(|chunks| bytemuck::cast_slice(chunks).to_vec())
        };
        send.write_all(&encode_block_header(k, bytes.is_some()))
            .await?;
        if let Some(bytes) = bytes {
            send.write_all(&bytes).await?;
        }
    }
    send.finish()?;
    Ok(())
}
