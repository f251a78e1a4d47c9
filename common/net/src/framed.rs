//! Control messages over a QUIC stream, framed by [`tessera_protocol::codec`].

use crate::NetError;
use serde::de::DeserializeOwned;
use serde::Serialize;
use tessera_protocol::codec;

/// Writes one message, length-prefixed.
pub async fn write_msg<T: Serialize>(
    send: &mut quinn::SendStream,
    msg: &T,
) -> Result<(), NetError> {
    send.write_all(&codec::encode(msg)?)
        .await
        .map_err(|e| match e {
            quinn::WriteError::ConnectionLost(lost) => closed_by_peer(lost, NetError::StreamClosed),
            e => NetError::StreamClosed(e.to_string()),
        })
}

/// A connection lost, as [`NetError::ClosedByPeer`] when the peer closed it on purpose (its
/// code and reason say why: a run that is over is not a master lost), else as `other` says.
fn closed_by_peer(lost: quinn::ConnectionError, other: fn(String) -> NetError) -> NetError {
    match lost {
        quinn::ConnectionError::ApplicationClosed(close) => NetError::ClosedByPeer {
            code: close.error_code.into_inner(),
            reason: String::from_utf8_lossy(&close.reason).into_owned(),
        },
        lost => other(format!("connection lost: {lost}")),
    }
}

/// Reads one message; `Ok(None)` when the peer finished the stream cleanly between messages.
pub async fn read_msg<T: DeserializeOwned>(
    recv: &mut quinn::RecvStream,
) -> Result<Option<T>, NetError> {
    let mut prefix = [0u8; 4];
    match recv.read_exact(&mut prefix).await {
        Ok(()) => {}
        Err(quinn::ReadExactError::FinishedEarly(0)) => return Ok(None),
        Err(quinn::ReadExactError::ReadError(quinn::ReadError::ConnectionLost(lost))) => {
            return Err(closed_by_peer(lost, NetError::StreamBroken))
        }
        Err(e) => return Err(NetError::StreamBroken(e.to_string())),
    }
    let len = codec::body_len(prefix)?;
    let mut body = vec![0u8; len];
    recv.read_exact(&mut body)
        .await
        .map_err(|e| NetError::StreamBroken(format!("control message cut short: {e}")))?;
    Ok(Some(codec::decode(&body)?))
}

/// Reads messages from `recv` in a task of its own and hands them over a channel, ending with
/// the stream's end (`Ok(None)`) or its error. Driver loops select on the channel, never on
/// [`read_msg`] itself: dropping a half-done `read_msg` (another branch won) would lose the
/// bytes it had read and leave the stream out of step.
pub fn spawn_reader<T: DeserializeOwned + Send + 'static>(
    mut recv: quinn::RecvStream,
) -> tokio::sync::mpsc::Receiver<Result<Option<T>, NetError>> {
    let (tx, rx) = tokio::sync::mpsc::channel(64);
    tokio::spawn(async move {
        loop {
            let msg = read_msg::<T>(&mut recv).await;
            let last = !matches!(msg, Ok(Some(_)));
            if tx.send(msg).await.is_err() || last {
                break;
            }
        }
    });
    rx
}
