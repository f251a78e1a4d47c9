//! Pixel streams, render node → display node: one stream header, then per tile an 8-byte header
//! and the tile's pixels, row-major RGB8, raw or LZ4-compressed as the stream header says. Tile
//! geometry is not sent: both ends derive it from the wall layout and the tile id, so the only
//! per-tile overhead is 8 bytes.
//!
//! In an LZ4 stream a tile's payload is an LZ4 block only when that is shorter than the raw
//! pixels; otherwise the raw pixels go as they are. The length in the tile header tells which
//! (equal to the tile's pixel bytes: raw; shorter: LZ4), so a tile never grows on the wire and
//! needs no flag of its own.

use crate::{FrameId, RenderNodeId};
use serde::{Deserialize, Serialize};
use tessera_model::state::StateId;
use tessera_model::wall::TileId;

/// The first 4 bytes of every pixel stream: a stream that starts otherwise is not Tessera's.
pub const STREAM_MAGIC: [u8; 4] = *b"TSPX";
/// Bytes of a [`StreamHeader`] on the wire.
pub const STREAM_HEADER_LEN: usize = 40;
/// Bytes of a [`TileHeader`] on the wire.
pub const TILE_HEADER_LEN: usize = 8;

/// Pixel formats; only RGB8 so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum PixelFormat {
    /// Three bytes a pixel: red, green, blue, 8 bits each, ready to show.
    Rgb8 = 1,
}

impl PixelFormat {
    /// Bytes one pixel takes.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Rgb8 => 3,
        }
    }
}

/// How tiles' pixels are packed in a pixel stream; one per run, carried in the
/// [`Session`](super::Session) so every render node sends what every display expects.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u16)]
#[serde(rename_all = "lowercase")]
pub enum Compression {
    /// Raw pixels: no CPU spent, as many bytes as pixels.
    #[default]
    None = 0,
    /// Each tile an LZ4 block (or raw where LZ4 does not make it shorter): for links slower
    /// than the render nodes.
    Lz4 = 1,
}

impl Compression {
    /// A tile's payload: `rgb` itself, or its LZ4 block if this stream compresses and that is
    /// shorter.
    pub fn encode_tile(self, rgb: Vec<u8>) -> Vec<u8> {
        match self {
            Compression::None => rgb,
            Compression::Lz4 => {
                let packed = lz4_flex::block::compress(&rgb);
                if packed.len() < rgb.len() {
                    packed
                } else {
                    rgb
                }
            }
        }
    }

    /// Checks a tile header's length before its payload is read: `pixel_bytes` is what the
    /// tile's geometry holds.
    pub fn check_tile_len(
        self,
        th: &TileHeader,
        pixel_bytes: usize,
    ) -> Result<(), PixelStreamError> {
        let len = th.byte_len as usize;
        let fits = match self {
            Compression::None => len == pixel_bytes,
            Compression::Lz4 => len > 0 && len <= pixel_bytes,
        };
        if fits {
            Ok(())
        } else {
            Err(PixelStreamError::TileLength {
                tile: th.tile.0,
                len: th.byte_len,
                pixel_bytes,
            })
        }
    }

    /// The tile's RGB from its payload (checked by [`Self::check_tile_len`]); corrupt or
    /// truncated LZ4 data, or data that does not unpack to exactly `pixel_bytes`, is an error.
    pub fn decode_tile(
        self,
        tile: TileId,
        payload: Vec<u8>,
        pixel_bytes: usize,
    ) -> Result<Vec<u8>, PixelStreamError> {
        if payload.len() == pixel_bytes {
            return Ok(payload);
        }
        let corrupt = |reason: String| PixelStreamError::CorruptTile {
            tile: tile.0,
            reason,
        };
        match self {
            Compression::None => Err(corrupt(format!(
                "{} bytes in a raw stream, expected {pixel_bytes}",
                payload.len()
            ))),
            Compression::Lz4 => {
                let mut rgb = vec![0u8; pixel_bytes];
                let n = lz4_flex::block::decompress_into(&payload, &mut rgb)
                    .map_err(|e| corrupt(e.to_string()))?;
                if n != pixel_bytes {
                    return Err(corrupt(format!(
                        "unpacks to {n} bytes, expected {pixel_bytes}"
                    )));
                }
                Ok(rgb)
            }
        }
    }
}

/// Why a pixel stream or one of its tiles was refused; the display drops the stream.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum PixelStreamError {
    /// The stream does not start with [`STREAM_MAGIC`].
    #[error("pixel stream does not start with the Tessera magic")]
    BadMagic,
    /// The stream header gives another protocol version than
    /// [`PROTOCOL_VERSION`](super::PROTOCOL_VERSION).
    #[error("pixel stream version {0} is not {expected}", expected = super::PROTOCOL_VERSION)]
    BadVersion(u16),
    /// The stream header names a [`PixelFormat`] this build does not know.
    #[error("unknown pixel format {0}")]
    BadFormat(u16),
    /// The stream header names a [`Compression`] this build does not know.
    #[error("unknown pixel compression {0}")]
    BadCompression(u16),
    /// The stream header announces more tiles than the receiving display owns.
    #[error("pixel stream announces {count} tiles, more than the {limit} this display owns")]
    TooManyTiles {
        /// Tiles the header announces.
        count: u32,
        /// Tiles the receiving display owns.
        limit: u32,
    },
    /// The stream header announces no tiles: render nodes never open an empty stream.
    #[error("pixel stream announces no tiles")]
    NoTiles,
    /// A tile header's length does not fit the tile's geometry: not exactly its pixel bytes in a
    /// raw stream, 0 or more than them in an LZ4 stream.
    #[error("tile {tile} carries {len} bytes for {pixel_bytes} bytes of pixels")]
    TileLength {
        /// The tile's id.
        tile: u32,
        /// Payload length its header gives, in bytes.
        len: u32,
        /// Bytes of the tile's raw pixels, from its geometry.
        pixel_bytes: usize,
    },
    /// A tile's payload does not unpack to exactly its pixel bytes.
    #[error("tile {tile} is corrupt: {reason}")]
    CorruptTile {
        /// The tile's id.
        tile: u32,
        /// What is wrong, for the log (LZ4's message, or the sizes that disagree).
        reason: String,
    },
}

/// The header at the start of each pixel stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StreamHeader {
    /// How the tiles' pixels are laid out.
    pub format: PixelFormat,
    /// How the tiles' pixels are packed; the session's.
    pub compression: Compression,
    /// The frame the tiles belong to.
    pub frame: FrameId,
    /// The wall state the tiles were rendered with (the frame start's).
    pub state: StateId,
    /// Tiles that follow in this stream, 1 to the number the receiving display owns.
    pub tile_count: u32,
    /// Who rendered the batch, and how long its tiles took, in microseconds: what a display
    /// shows in its overlay, and nothing it trusts for anything else.
    pub source: BatchSource,
}

/// Who rendered a batch of tiles, and in how long.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BatchSource {
    /// The render node that rendered the batch.
    pub node: RenderNodeId,
    /// Rendering time of one tile, averaged over the batch, microseconds.
    pub render_us: u32,
}

impl StreamHeader {
    /// The header's [`STREAM_HEADER_LEN`] bytes, little-endian: magic, protocol version (u16),
    /// format (u16), frame (u64), tile count (u32), compression (u16), 2 zero bytes, state (u64),
    /// render node (u32), render time (u32).
    pub fn encode(&self) -> [u8; STREAM_HEADER_LEN] {
        let mut out = [0u8; STREAM_HEADER_LEN];
        out[0..4].copy_from_slice(&STREAM_MAGIC);
        out[4..6].copy_from_slice(&(super::PROTOCOL_VERSION as u16).to_le_bytes());
        out[6..8].copy_from_slice(&(self.format as u16).to_le_bytes());
        out[8..16].copy_from_slice(&self.frame.0.to_le_bytes());
        out[16..20].copy_from_slice(&self.tile_count.to_le_bytes());
        out[20..22].copy_from_slice(&(self.compression as u16).to_le_bytes());
        // 22..24 stay zero: alignment for the state id.
        out[24..32].copy_from_slice(&self.state.0.to_le_bytes());
        out[32..36].copy_from_slice(&self.source.node.0.to_le_bytes());
        out[36..40].copy_from_slice(&self.source.render_us.to_le_bytes());
        out
    }

    /// Parses and checks a header; `max_tiles` is how many tiles the receiving display owns.
    ///
    /// # Errors
    /// Another magic or protocol version, an unknown format or compression, no tiles or more
    /// than `max_tiles`.
    pub fn decode(
        bytes: &[u8; STREAM_HEADER_LEN],
        max_tiles: u32,
    ) -> Result<Self, PixelStreamError> {
        if bytes[0..4] != STREAM_MAGIC {
            return Err(PixelStreamError::BadMagic);
        }
        let u16_at = |i: usize| u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        let version = u16_at(4);
        if version as u32 != super::PROTOCOL_VERSION {
            return Err(PixelStreamError::BadVersion(version));
        }
        let format = match u16_at(6) {
            1 => PixelFormat::Rgb8,
            other => return Err(PixelStreamError::BadFormat(other)),
        };
        let compression = match u16_at(20) {
            0 => Compression::None,
            1 => Compression::Lz4,
            other => return Err(PixelStreamError::BadCompression(other)),
        };
        let frame = FrameId(u64::from_le_bytes(
            bytes[8..16].try_into().expect("8 bytes"),
        ));
        let tile_count = u32::from_le_bytes(bytes[16..20].try_into().expect("4 bytes"));
        if tile_count == 0 {
            return Err(PixelStreamError::NoTiles);
        }
        if tile_count > max_tiles {
            return Err(PixelStreamError::TooManyTiles {
                count: tile_count,
                limit: max_tiles,
            });
        }
        let u32_at = |i: usize| u32::from_le_bytes(bytes[i..i + 4].try_into().expect("4 bytes"));
        Ok(StreamHeader {
            format,
            compression,
            frame,
            state: StateId(u64::from_le_bytes(
                bytes[24..32].try_into().expect("8 bytes"),
            )),
            tile_count,
            source: BatchSource {
                node: RenderNodeId(u32_at(32)),
                render_us: u32_at(36),
            },
        })
    }
}

/// The header before each tile's payload. The length is checked against the tile's geometry
/// ([`Compression::check_tile_len`]) before any pixel is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileHeader {
    /// The tile the payload is the pixels of.
    pub tile: TileId,
    /// Length of the payload that follows, in bytes: the raw pixels' length, or less for an LZ4
    /// block.
    pub byte_len: u32,
}

impl TileHeader {
    /// The header's [`TILE_HEADER_LEN`] bytes: tile id, then payload length, each a
    /// little-endian u32.
    pub fn encode(&self) -> [u8; TILE_HEADER_LEN] {
        let mut out = [0u8; TILE_HEADER_LEN];
        out[0..4].copy_from_slice(&self.tile.0.to_le_bytes());
        out[4..8].copy_from_slice(&self.byte_len.to_le_bytes());
        out
    }

    /// Reads a tile header; its length is checked later, against the tile's geometry.
    pub fn decode(bytes: &[u8; TILE_HEADER_LEN]) -> Self {
        TileHeader {
            tile: TileId(u32::from_le_bytes(bytes[0..4].try_into().expect("4 bytes"))),
            byte_len: u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes")),
        }
    }
}

/// One stream's bytes: the header, then every tile's payload (from [`Compression::encode_tile`]
/// with the same `compression`), in one buffer so it goes out in one write.
pub fn encode_batch<'a>(
    (frame, state): (FrameId, StateId),
    source: BatchSource,
    compression: Compression,
    tiles: impl ExactSizeIterator<Item = (TileId, &'a [u8])>,
) -> Vec<u8> {
    let header = StreamHeader {
        format: PixelFormat::Rgb8,
        compression,
        frame,
        state,
        tile_count: tiles.len() as u32,
        source,
    };
    let mut out = header.encode().to_vec();
    for (tile, payload) in tiles {
        out.extend_from_slice(
            &TileHeader {
                tile,
                byte_len: payload.len() as u32,
            }
            .encode(),
        );
        out.extend_from_slice(payload);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn header_round_trips_and_checks_limits() {
        let h = StreamHeader {
            format: PixelFormat::Rgb8,
            compression: Compression::Lz4,
            frame: FrameId(77),
            state: StateId(u64::MAX - 3),
            tile_count: 5,
            source: BatchSource {
                node: RenderNodeId(9),
                render_us: 12_345,
            },
        };
        assert_eq!(StreamHeader::decode(&h.encode(), 5), Ok(h));
        assert_eq!(
            StreamHeader::decode(&h.encode(), 4),
            Err(PixelStreamError::TooManyTiles { count: 5, limit: 4 })
        );
        let mut bad = h.encode();
        bad[0] = b'X';
        assert_eq!(
            StreamHeader::decode(&bad, 5),
            Err(PixelStreamError::BadMagic)
        );
        let mut bad = h.encode();
        bad[6] = 9;
        assert_eq!(
            StreamHeader::decode(&bad, 5),
            Err(PixelStreamError::BadFormat(9))
        );
        let mut bad = h.encode();
        bad[20] = 7;
        assert_eq!(
            StreamHeader::decode(&bad, 5),
            Err(PixelStreamError::BadCompression(7))
        );
    }

    /// A 64×64 tile of flat bands of colour, as a background renders.
    fn smooth_tile() -> Vec<u8> {
        (0..64 * 64)
            .flat_map(|i| [(i / 512 * 30) as u8, 90, 160])
            .collect()
    }

    /// Bytes no compressor can shorten (a fixed xorshift sequence).
    fn noise_tile() -> Vec<u8> {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        (0..64 * 64 * 3)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 24) as u8
            })
            .collect()
    }

    fn round_trip(c: Compression, rgb: &[u8]) -> Vec<u8> {
        let payload = c.encode_tile(rgb.to_vec());
        let th = TileHeader {
            tile: TileId(3),
            byte_len: payload.len() as u32,
        };
        c.check_tile_len(&th, rgb.len()).unwrap();
        let back = c
            .decode_tile(TileId(3), payload.clone(), rgb.len())
            .unwrap();
        assert_eq!(back, rgb);
        payload
    }

    #[test]
    fn tiles_round_trip_and_lz4_never_grows_a_tile() {
        for rgb in [smooth_tile(), noise_tile(), vec![0; 64 * 64 * 3]] {
            assert_eq!(round_trip(Compression::None, &rgb), rgb);
            assert!(round_trip(Compression::Lz4, &rgb).len() <= rgb.len());
        }
        assert!(round_trip(Compression::Lz4, &smooth_tile()).len() < smooth_tile().len() / 2);
        // Noise goes raw, byte for byte.
        assert_eq!(round_trip(Compression::Lz4, &noise_tile()), noise_tile());
    }

    #[test]
    fn truncated_or_corrupt_lz4_tiles_are_errors() {
        let rgb = smooth_tile();
        let packed = Compression::Lz4.encode_tile(rgb.clone());
        assert!(packed.len() < rgb.len());
        for cut in [1, packed.len() / 2, packed.len() - 1] {
            let r = Compression::Lz4.decode_tile(TileId(1), packed[..cut].to_vec(), rgb.len());
            assert!(
                matches!(r, Err(PixelStreamError::CorruptTile { tile: 1, .. })),
                "cut at {cut}: {r:?}"
            );
        }
        // A valid block that unpacks to fewer bytes than the tile holds.
        let short = Compression::Lz4.encode_tile(vec![0; rgb.len() / 2]);
        assert!(Compression::Lz4
            .decode_tile(TileId(1), short, rgb.len())
            .is_err());
        // A raw stream's tile must be exactly the tile's pixels.
        assert!(Compression::None
            .decode_tile(TileId(1), packed, rgb.len())
            .is_err());
    }

    #[test]
    fn tile_lengths_are_checked_before_reading() {
        let th = |byte_len| TileHeader {
            tile: TileId(9),
            byte_len,
        };
        assert!(Compression::None.check_tile_len(&th(300), 300).is_ok());
        assert_eq!(
            Compression::None.check_tile_len(&th(299), 300),
            Err(PixelStreamError::TileLength {
                tile: 9,
                len: 299,
                pixel_bytes: 300
            })
        );
        assert!(Compression::Lz4.check_tile_len(&th(299), 300).is_ok());
        assert!(Compression::Lz4.check_tile_len(&th(300), 300).is_ok());
        assert!(Compression::Lz4.check_tile_len(&th(301), 300).is_err());
        assert!(Compression::Lz4.check_tile_len(&th(0), 300).is_err());
    }

    proptest! {
        #[test]
        fn random_headers_never_panic(bytes in proptest::collection::vec(any::<u8>(), STREAM_HEADER_LEN), max in any::<u32>()) {
            let bytes: [u8; STREAM_HEADER_LEN] = bytes.try_into().unwrap();
            let _ = StreamHeader::decode(&bytes, max);
        }

        #[test]
        fn random_lz4_payloads_never_panic(payload in proptest::collection::vec(any::<u8>(), 1..512), pixel_bytes in 1usize..2048) {
            if let Ok(rgb) = Compression::Lz4.decode_tile(TileId(0), payload, pixel_bytes) {
                prop_assert_eq!(rgb.len(), pixel_bytes);
            }
        }

        #[test]
        fn any_tile_round_trips(rgb in proptest::collection::vec(0u8..4, 1..2048)) {
            round_trip(Compression::Lz4, &rgb);
        }
    }
}
