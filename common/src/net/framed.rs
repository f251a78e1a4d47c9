//! Control messages over a QUIC stream, framed by [`crate::protocol::codec`].

use crate::protocol::codec;
use anyhow::{Context, Result};
use serde::de::DeserializeOwned;
use serde::Serialize;

pub async fn write_msg<T: Serialize>(send: &mut quinn::SendStream, msg: &T) -> Result<()> {
    send.write_all(&codec::encode(msg))
        .await
        .context("control stream closed")?;
    Ok(())
}

/// Reads one message; `Ok(None)` when the peer finished the stream cleanly between messages.
pub async fn read_msg<T: DeserializeOwned>(recv: &mut quinn::RecvStream) -> Result<Option<T>> {
    let mut prefix = [0u8; 4];
    match recv.read_exact(&mut prefix).await {
        Ok(()) => {}
        Err(quinn::ReadExactError::FinishedEarly(0)) => return Ok(None),
        Err(e) => return Err(e).context("control stream broken"),
    }
    let len = codec::body_len(prefix)?;
    let mut body = vec![0u8; len];
    recv.read_exact(&mut body)
        .await
        .context("control message cut short")?;
    Ok(Some(codec::decode(&body)?))
}
