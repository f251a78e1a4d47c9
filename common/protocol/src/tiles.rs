//! Ranges of tile ids, as assignments and requests carry them.

use crate::ProtocolError;
use serde::{Deserialize, Serialize};
use tessera_model::wall::TileId;

/// Tiles `start..end` (ids). Assignments are mostly contiguous, so ranges keep them small.
/// `start <= end` always; whether the tiles exist is for the receiver, who knows the wall.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct TileRange {
    pub(crate) start: u32,
    pub(crate) end: u32,
}

#[derive(Deserialize)]
struct TileRangeRaw {
    pub(crate) start: u32,
    pub(crate) end: u32,
}

impl TryFrom<TileRangeRaw> for TileRange {
    type Error = ProtocolError;

    fn try_from(raw: TileRangeRaw) -> Result<Self, ProtocolError> {
        TileRange::new(raw.start, raw.end)
    }
}

impl<'de> Deserialize<'de> for TileRange {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        tessera_model::checked::deserialize::<D, TileRangeRaw, Self>(d)
    }
}

impl TileRange {
    /// Tiles `start..end`.
    ///
    /// # Errors
    /// `end < start`.
    pub fn new(start: u32, end: u32) -> Result<Self, ProtocolError> {
        if end < start {
            return Err(ProtocolError::BackwardRange { start, end });
        }
        Ok(TileRange { start, end })
    }

    /// The single tile `tile`.
    pub fn one(tile: TileId) -> Self {
        TileRange {
            start: tile.0,
            end: tile.0.saturating_add(1),
        }
    }

    /// The first tile id.
    pub fn start(self) -> u32 {
        self.start
    }

    /// One past the last tile id.
    pub fn end(self) -> u32 {
        self.end
    }

    /// The tile ids, in increasing order.
    pub fn tiles(self) -> impl Iterator<Item = TileId> {
        (self.start..self.end).map(TileId)
    }

    /// How many tiles the range holds.
    pub fn len(self) -> usize {
        self.end.saturating_sub(self.start) as usize
    }

    /// Whether the range holds no tile (`start == end`).
    pub fn is_empty(self) -> bool {
        self.len() == 0
    }
}

/// Compresses a sorted-or-not list of tile ids into ranges of consecutive ids.
pub fn to_ranges(tiles: impl IntoIterator<Item = TileId>) -> Vec<TileRange> {
    let mut ranges: Vec<TileRange> = Vec::new();
    for TileId(t) in tiles {
        match ranges.last_mut() {
            Some(r) if r.end == t => r.end += 1,
            _ => ranges.push(TileRange::one(TileId(t))),
        }
    }
    ranges
}
