//! Control-message framing: a 4-byte little-endian length, then a postcard body.
//!
//! This is the only place that knows the codec, so replacing postcard touches one file.

use serde::de::DeserializeOwned;
use serde::Serialize;

/// Largest control message body accepted. A session with a few thousand displays fits easily;
/// anything bigger is a bug or an attack.
pub const MAX_CONTROL_BODY: usize = 1 << 20;

/// Why a control message could not be framed or read.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CodecError {
    /// A body (to send, or announced by a length prefix) is over [`MAX_CONTROL_BODY`] bytes.
    #[error("control message of {len} bytes exceeds the {limit}-byte limit")]
    TooLarge {
        /// The body's length, in bytes.
        len: usize,
        /// The most accepted, [`MAX_CONTROL_BODY`].
        limit: usize,
    },
    /// A length prefix announces a body of 0 bytes: no message is empty.
    #[error("empty control message")]
    Empty,
    /// The bytes are not a postcard encoding of the expected type (or, when encoding, the value
    /// could not be serialized); carries postcard's message.
    #[error("malformed control message: {0}")]
    Malformed(String),
    /// A body decoded with this many bytes left over.
    #[error("control message has {0} trailing bytes")]
    Trailing(usize),
    /// The body decoded, but a value broke its type's invariant; carries the check's refusal.
    #[error("invalid control message: {0}")]
    Invalid(String),
}

/// Encodes `msg` as one frame (length prefix included).
///
/// # Errors
/// [`CodecError::TooLarge`] if the body would be over [`MAX_CONTROL_BODY`], which the peer
/// would refuse; the types that travel are bounded so that this does not happen, but a sender
/// gets an error to report rather than a frame nobody reads.
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>, CodecError> {
    let mut frame =
        postcard::to_extend(msg, vec![0u8; 4]).map_err(|e| CodecError::Malformed(e.to_string()))?;
    let len = frame.len() - 4;
    if len > MAX_CONTROL_BODY {
        return Err(CodecError::TooLarge {
            len,
            limit: MAX_CONTROL_BODY,
        });
    }
    frame[..4].copy_from_slice(&(len as u32).to_le_bytes());
    Ok(frame)
}

/// Reads the body length from a frame's prefix, refusing absurd sizes before any allocation.
pub fn body_len(prefix: [u8; 4]) -> Result<usize, CodecError> {
    let len = u32::from_le_bytes(prefix) as usize;
    if len == 0 {
        return Err(CodecError::Empty);
    }
    if len > MAX_CONTROL_BODY {
        return Err(CodecError::TooLarge {
            len,
            limit: MAX_CONTROL_BODY,
        });
    }
    Ok(len)
}

/// Decodes a frame body; every byte must be used.
pub fn decode<T: DeserializeOwned>(body: &[u8]) -> Result<T, CodecError> {
    if body.len() > MAX_CONTROL_BODY {
        return Err(CodecError::TooLarge {
            len: body.len(),
            limit: MAX_CONTROL_BODY,
        });
    }
    tessera_model::checked::clear();
    let (msg, rest) = postcard::take_from_bytes(body).map_err(|e| {
        // A value that parsed but broke an invariant says which; anything else is garbage.
        tessera_model::checked::take_refusal()
            .map_or_else(|| CodecError::Malformed(e.to_string()), CodecError::Invalid)
    })?;
    if !rest.is_empty() {
        return Err(CodecError::Trailing(rest.len()));
    }
    Ok(msg)
}

/// Decodes one whole frame (prefix and body) from a buffer, for tests and in-memory transports.
pub fn decode_frame<T: DeserializeOwned>(frame: &[u8]) -> Result<T, CodecError> {
    let prefix: [u8; 4] = frame
        .get(..4)
        .and_then(|p| p.try_into().ok())
        .ok_or_else(|| CodecError::Malformed("frame shorter than its length prefix".into()))?;
    let len = body_len(prefix)?;
    let body = &frame[4..];
    if body.len() != len {
        return Err(CodecError::Malformed(format!(
            "frame says {len} bytes but carries {}",
            body.len()
        )));
    }
    decode(body)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::*;
    use glam::Vec3;
    use proptest::prelude::*;
    use tessera_model::camera::Camera;
    use tessera_model::params::{RenderParams, RenderParamsSpec};
    use tessera_model::wall::{DisplayId, WallSpec};

    fn samples() -> Vec<FromNode> {
        vec![
            FromNode::Hello(Hello {
                version: PROTOCOL_VERSION,
                role: Role::Display {
                    display: DisplayId(3),
                    pixel_addr: "127.0.0.1:4000".parse().unwrap(),
                },
                host: "wall-3".into(),
            }),
            FromNode::TilesDone {
                frame: FrameId(9),
                tiles: vec![TileRange::new(4, 90).unwrap()],
                want_more: true,
            },
            FromNode::Stats(NodeStats::Render(RenderStats {
                tiles: 5,
                rays: 1 << 40,
                busy_s: 1.5,
                elapsed_s: 2.0,
                volume_load_s: vec![0.25, 0.5],
                prefetch_hits: 7,
                prefetch_misses: 1,
                volume_stall_s: 0.25,
                max_rss_bytes: 123 << 20,
                dsm: Some(Box::new(crate::dsm::DsmStats {
                    rank: Some(1),
                    fetched: 9,
                    latency_p99_us: 350.5,
                    ..Default::default()
                })),
            })),
            FromNode::BlocksAt {
                addr: "10.0.0.7:7401".parse().unwrap(),
            },
            FromNode::StaleMaster { seen: 4 },
            FromNode::Loading {
                step: crate::LoadStep::BuildingBvh {
                    triangles: 2_180_000,
                },
                elapsed_s: 14,
            },
        ]
    }

    fn to_node_samples() -> Vec<ToNode> {
        vec![
            ToNode::Welcome {
                node: Some(RenderNodeId(2)),
                session: Session::new(SessionSpec {
                    wall: WallSpec::grid(2, 2, 480, 270).bezel(16).build().unwrap(),
                    scene: tessera_model::scene_spec::SceneSpec::default(),
                    scene_hash: [7; 32],
                    displays: vec![DisplayEndpoint {
                        display: DisplayId(0),
                        addr: "[::1]:9".parse().unwrap(),
                    }],
                    save_frame: Some(FrameId(3)),
                    compression: crate::pixels::Compression::Lz4,
                    windows: [(
                        0,
                        tessera_model::window::WindowPlacement {
                            position: Some((-10, 20)),
                            ..Default::default()
                        },
                    )]
                    .into(),
                    data: crate::dsm::DataSpec::Dsm(crate::dsm::DsmSpec {
                        dir: "/var/tessera/prepared".into(),
                        block_bytes: 8192,
                        ranks: 4,
                        replicas: 2,
                        memory_budget: Some(512 << 20),
                        cache_fraction: None,
                    }),
                    particle_range: Some([-1.5, 2.0]),
                })
                .unwrap(),
                term: 3,
            },
            ToNode::BlockHolders {
                rank: Some(2),
                holders: vec![crate::dsm::BlockHolder {
                    rank: 0,
                    addr: "127.0.0.1:5000".parse().unwrap(),
                }],
            },
            ToNode::FrameStart(FrameStart {
                lights: Some(
                    tessera_model::light::Lights::new(&[tessera_model::light::Light::directional(
                        Vec3::Y,
                        0.5,
                    )])
                    .unwrap(),
                ),
                ..FrameStart::new(
                    FrameId(1),
                    tessera_model::state::StateId(7),
                    Camera::new(Vec3::ONE, Vec3::ZERO, Vec3::Y, 40.0).unwrap(),
                    RenderParams::interactive(),
                )
            }),
            ToNode::Present {
                frame: FrameId(u64::MAX),
            },
        ]
    }

    #[test]
    fn messages_round_trip() {
        for msg in samples() {
            assert_eq!(
                decode_frame::<FromNode>(&encode(&msg).unwrap()).unwrap(),
                msg
            );
        }
        for msg in to_node_samples() {
            assert_eq!(decode_frame::<ToNode>(&encode(&msg).unwrap()).unwrap(), msg);
        }
    }

    #[test]
    fn truncated_frames_are_errors() {
        for msg in to_node_samples() {
            let frame = encode(&msg).unwrap();
            for cut in 0..frame.len() {
                assert!(
                    decode_frame::<ToNode>(&frame[..cut]).is_err(),
                    "cut at {cut}"
                );
            }
        }
    }

    #[test]
    fn oversized_frames_are_refused_before_reading_the_body() {
        let prefix = ((MAX_CONTROL_BODY + 1) as u32).to_le_bytes();
        assert!(matches!(body_len(prefix), Err(CodecError::TooLarge { .. })));
        assert_eq!(
            body_len(u32::MAX.to_le_bytes()),
            Err(CodecError::TooLarge {
                len: u32::MAX as usize,
                limit: MAX_CONTROL_BODY
            })
        );
        assert_eq!(body_len([0; 4]), Err(CodecError::Empty));
    }

    #[test]
    fn trailing_bytes_are_refused() {
        let mut frame = encode(&ToNode::Shutdown).unwrap();
        frame.push(0);
        let len = (frame.len() - 4) as u32;
        frame[..4].copy_from_slice(&len.to_le_bytes());
        assert!(matches!(
            decode_frame::<ToNode>(&frame),
            Err(CodecError::Trailing(1))
        ));
    }

    #[test]
    fn a_message_over_the_limit_is_an_error_not_a_panic() {
        let huge = FromNode::Failed {
            message: "x".repeat(MAX_CONTROL_BODY + 1),
        };
        assert!(matches!(encode(&huge), Err(CodecError::TooLarge { .. })));
    }

    #[test]
    fn a_frame_start_claiming_five_cut_planes_is_refused_by_name() {
        // The planes travel as a list; a peer can claim five even though we never send them.
        #[derive(serde::Serialize)]
        struct RawParams {
            shadows: bool,
            ao_samples: u32,
            ao_range: f32,
            crop: Option<(f32, f32)>,
            cuts: Vec<[f32; 4]>,
            spp: u32,
            first_sample: u32,
            volume: tessera_model::volume_params::VolumeParams,
        }
        #[allow(clippy::large_enum_variant)]
        #[derive(serde::Serialize)]
        enum RawToNode {
            _Welcome,
            _Refused,
            FrameStart(
                FrameId,
                tessera_model::state::StateId,
                Camera,
                RawParams,
                Option<()>,
            ),
        }
        let i = RenderParamsSpec::INTERACTIVE;
        let msg = RawToNode::FrameStart(
            FrameId(1),
            tessera_model::state::StateId(1),
            Camera::new(Vec3::ONE, Vec3::ZERO, Vec3::Y, 40.0).unwrap(),
            RawParams {
                shadows: i.shadows,
                ao_samples: i.ao_samples,
                ao_range: i.ao_range,
                crop: i.crop,
                cuts: vec![[1.0, 0.0, 0.0, 0.0]; 5],
                spp: i.spp,
                first_sample: i.first_sample,
                volume: i.volume,
            },
            None,
        );
        let err = decode_frame::<ToNode>(&encode(&msg).unwrap()).unwrap_err();
        assert!(
            matches!(&err, CodecError::Invalid(why) if why.contains("at most 4 cutting planes")),
            "{err}"
        );
    }

    proptest! {
        #[test]
        fn random_bodies_never_panic(body in proptest::collection::vec(any::<u8>(), 0..512)) {
            let _ = decode::<ToNode>(&body);
            let _ = decode::<FromNode>(&body);
        }

        #[test]
        fn corrupted_messages_never_panic(index in 0usize..64, byte in any::<u8>(), which in 0usize..3) {
            let mut frame = encode(&to_node_samples()[which]).unwrap();
            let i = 4 + index % (frame.len() - 4);
            frame[i] = byte;
            let _ = decode_frame::<ToNode>(&frame);
        }
    }
}
