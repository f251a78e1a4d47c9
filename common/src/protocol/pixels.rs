//! Pixel streams, render node → display node: one stream header, then per tile an 8-byte header
//! and the tile's RGB8 pixels, row-major. Tile geometry is not sent: both ends derive it from the
//! wall layout and the tile id, so the only per-tile overhead is 8 bytes.

use crate::protocol::FrameId;
use crate::wall::TileId;

pub const STREAM_MAGIC: [u8; 4] = *b"TSPX";
pub const STREAM_HEADER_LEN: usize = 24;
pub const TILE_HEADER_LEN: usize = 8;

/// Pixel formats; only RGB8 so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum PixelFormat {
    Rgb8 = 1,
}

impl PixelFormat {
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Rgb8 => 3,
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum PixelStreamError {
    #[error("pixel stream does not start with the Tessera magic")]
    BadMagic,
    #[error("pixel stream version {0} is not {expected}", expected = super::PROTOCOL_VERSION)]
    BadVersion(u16),
    #[error("unknown pixel format {0}")]
    BadFormat(u16),
    #[error("pixel stream announces {count} tiles, more than the {limit} this display owns")]
    TooManyTiles { count: u32, limit: u32 },
    #[error("pixel stream announces no tiles")]
    NoTiles,
}

/// The header at the start of each pixel stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StreamHeader {
    pub format: PixelFormat,
    pub frame: FrameId,
    pub tile_count: u32,
}

impl StreamHeader {
    pub fn encode(&self) -> [u8; STREAM_HEADER_LEN] {
        let mut out = [0u8; STREAM_HEADER_LEN];
        out[0..4].copy_from_slice(&STREAM_MAGIC);
        out[4..6].copy_from_slice(&(super::PROTOCOL_VERSION as u16).to_le_bytes());
        out[6..8].copy_from_slice(&(self.format as u16).to_le_bytes());
        out[8..16].copy_from_slice(&self.frame.0.to_le_bytes());
        out[16..20].copy_from_slice(&self.tile_count.to_le_bytes());
        out
    }

    /// Parses and checks a header; `max_tiles` is how many tiles the receiving display owns.
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
        Ok(StreamHeader {
            format,
            frame,
            tile_count,
        })
    }
}

/// The header before each tile's pixels. The length is checked against the tile's geometry by
/// the frame assembler before any pixel is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileHeader {
    pub tile: TileId,
    pub byte_len: u32,
}

impl TileHeader {
    pub fn encode(&self) -> [u8; TILE_HEADER_LEN] {
        let mut out = [0u8; TILE_HEADER_LEN];
        out[0..4].copy_from_slice(&self.tile.0.to_le_bytes());
        out[4..8].copy_from_slice(&self.byte_len.to_le_bytes());
        out
    }

    pub fn decode(bytes: &[u8; TILE_HEADER_LEN]) -> Self {
        TileHeader {
            tile: TileId(u32::from_le_bytes(bytes[0..4].try_into().expect("4 bytes"))),
            byte_len: u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes")),
        }
    }
}

/// One stream's bytes: the header, then every tile, in one buffer so it goes out in one write.
pub fn encode_batch<'a>(
    frame: FrameId,
    tiles: impl ExactSizeIterator<Item = (TileId, &'a [u8])>,
) -> Vec<u8> {
    let header = StreamHeader {
        format: PixelFormat::Rgb8,
        frame,
        tile_count: tiles.len() as u32,
    };
    let mut out = header.encode().to_vec();
    for (tile, pixels) in tiles {
        out.extend_from_slice(
            &TileHeader {
                tile,
                byte_len: pixels.len() as u32,
            }
            .encode(),
        );
        out.extend_from_slice(pixels);
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
            frame: FrameId(77),
            tile_count: 5,
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
    }

    proptest! {
        #[test]
        fn random_headers_never_panic(bytes in proptest::array::uniform24(any::<u8>()), max in any::<u32>()) {
            let _ = StreamHeader::decode(&bytes, max);
        }
    }
}
