//! The display node's sans-IO core: puts tiles together into frames and hands a frame over for
//! presentation only when the master says so.
//!
//! It checks every tile against the wall before it touches a pixel: a tile of another display,
//! a wrong length, or a frame outside the window of frames in flight is an error, and the driver
//! closes the offending connection. Up to [`FRAMES_AHEAD`] frames are assembled at once, so
//! frame f+1 can arrive while f waits for the swap barrier.
//!
//! Every tile also says which wall state it was rendered with. A frame whose tiles disagree, or
//! disagree with the state its `FrameStart` announced, is never presented: the tile that breaks
//! the rule is refused, and presenting such a frame is an error. (Tiles travel from render
//! nodes and may arrive before the display hears of the frame from the master, so the first
//! tile's state is kept and checked again once the frame's state is known.)

use std::collections::BTreeMap;
use tessera_model::state::StateId;
use tessera_model::wall::{ScreenRect, Tile, TileGrid, TileId};
use tessera_protocol::FrameId;

/// Frames beyond the next one to present that may be under assembly.
pub const FRAMES_AHEAD: u64 = 3;

/// Why a display refuses a tile, a frame start or a present.
///
/// Each means the peer that sent it broke the protocol: the driver closes its connection.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AssembleError {
    /// The tile (its wall-wide index) lies on another display's screen, or on no screen.
    #[error("tile {0} does not belong to this display")]
    NotMine(u32),
    /// The tile's pixels are not exactly its width × height × 3 bytes of RGB8.
    #[error("tile {tile} carries {got} bytes, expected {expected}")]
    WrongLength {
        /// The tile's wall-wide index.
        tile: u32,
        /// The tile's pixel count × 3.
        expected: usize,
        /// The byte length the message carried.
        got: usize,
    },
    /// The frame is older than the next one to present: this display already showed it.
    #[error("frame {0:?} was already presented")]
    Stale(FrameId),
    /// The frame is [`FRAMES_AHEAD`] or more frames past the next one to present.
    #[error("frame {frame:?} is too far ahead of frame {next:?}, the next to present")]
    TooFarAhead {
        /// The frame the message was for.
        frame: FrameId,
        /// The next frame this display will present.
        next: FrameId,
    },
    /// The master said to present a frame some of whose tiles are still missing.
    #[error("asked to present frame {0:?}, which is not complete")]
    Incomplete(FrameId),
    /// A tile was rendered with another wall state than its frame's.
    #[error("tile {tile} of frame {frame:?} was rendered with state {got:?}, but the frame's is {expected:?}")]
    WrongState {
        /// The frame the tile belongs to.
        frame: FrameId,
        /// The tile's wall-wide index; at a present, the display's first tile, since the
        /// offending one is no longer known.
        tile: u32,
        /// The state the tile says it was rendered with.
        got: StateId,
        /// The frame's state: from its `FrameStart`, or else from its first tile.
        expected: StateId,
    },
    /// The master said to present a frame whose `FrameStart` never arrived here.
    #[error("asked to present frame {0:?} before its frame start said its state")]
    UnknownState(FrameId),
}

struct Partial {
    image: Vec<u8>,
    have: Vec<bool>,
    missing: usize,
    /// The state of the frame's first tile; every other tile must have the same.
    state: StateId,
}

/// A frame ready to show: the screen's pixels, RGB8, row-major.
#[derive(Debug)]
pub struct PresentedFrame {
    /// The frame these pixels are.
    pub frame: FrameId,
    /// The screen's width in pixels.
    pub width: u32,
    /// The screen's height in pixels.
    pub height: u32,
    /// `width × height` pixels, 3 bytes each, top row first.
    pub rgb: Vec<u8>,
}

/// One display's frames under assembly, and the swap barrier's side of presenting them.
///
/// # Examples
///
/// ```
/// use tessera_core::assemble::{AssembleError, FrameAssembler};
/// use tessera_protocol::FrameId;
/// use tessera_model::state::StateId;
/// use tessera_model::wall::{DisplayId, TileGrid, WallSpec};
///
/// // Two 32×16 screens in 16-pixel tiles: display 1 owns tiles 2 and 3.
/// let wall = WallSpec::grid(2, 1, 32, 16).tile_size(16).build().unwrap();
/// let grid = TileGrid::new(wall.clone());
/// let mut display = FrameAssembler::new(&grid, wall.screen(DisplayId(1)).unwrap());
/// let tile = |id: usize| &grid.tiles()[id];
/// let pixels = vec![200u8; 16 * 16 * 3];
///
/// // A tile of another display is refused before a pixel is read.
/// let (frame, state) = (FrameId(0), StateId(1));
/// assert_eq!(display.handle_tile(frame, state, tile(0).id, &pixels), Err(AssembleError::NotMine(0)));
/// assert_eq!(display.handle_tile(frame, state, tile(2).id, &pixels), Ok(None));
/// // The last tile completes the frame; the master hears of it once.
/// assert_eq!(display.handle_tile(frame, state, tile(3).id, &pixels), Ok(Some(frame)));
/// assert_eq!(display.poll_complete(), Some(FrameId(0)));
/// assert_eq!(display.poll_complete(), None);
/// // It is shown only when the master says so, and only as the state its frame start said.
/// display.handle_frame_start(frame, state)?;
/// let shown = display.handle_present(frame)?;
/// assert_eq!((shown.width, shown.height, shown.rgb.len()), (32, 16, 32 * 16 * 3));
/// # Ok::<(), AssembleError>(())
/// ```
pub struct FrameAssembler {
    screen: ScreenRect,
    tiles: Vec<Tile>,
    first_tile: u32,
    frames: BTreeMap<FrameId, Partial>,
    /// States announced by the frame starts of frames not yet presented.
    states: BTreeMap<FrameId, StateId>,
    next_present: FrameId,
    duplicates: u64,
    /// The last frame [`FrameAssembler::poll_complete`] handed out.
    reported_complete: Option<FrameId>,
}

impl FrameAssembler {
    /// An assembler for the display whose screen is `screen`, owning the tiles of `grid` on
    /// it; the first frame it expects is frame 0 (see [`FrameAssembler::start_at`]).
    pub fn new(grid: &TileGrid, screen: ScreenRect) -> Self {
        let tiles = grid.display_tiles(screen.id).to_vec();
        let first_tile = tiles.first().map_or(0, |t| t.id.0);
        FrameAssembler {
            screen,
            tiles,
            first_tile,
            frames: BTreeMap::new(),
            states: BTreeMap::new(),
            next_present: FrameId(0),
            duplicates: 0,
            reported_complete: None,
        }
    }

    /// How many tiles make one frame of this display.
    pub fn tile_count(&self) -> u32 {
        self.tiles.len() as u32
    }

    /// How many tiles arrived a second time (or after their frame was presented) and were
    /// ignored, since this assembler was made.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }

    /// Whether every tile of `frame` is here (and it is not presented yet).
    pub fn is_complete(&self, frame: FrameId) -> bool {
        self.frames.get(&frame).is_some_and(|p| p.missing == 0)
    }

    /// The next frame this display will present; older frames are stale.
    pub fn next_present(&self) -> FrameId {
        self.next_present
    }

    /// The first frame this display will show is `frame` (it joined a running wall): frames
    /// before it are stale, and the window of frames accepted ahead starts there. Only ever
    /// moves forward, and only before any frame started here.
    pub fn start_at(&mut self, frame: FrameId) {
        if self.states.is_empty() && self.frames.is_empty() && frame > self.next_present {
            self.next_present = frame;
        }
    }

    /// The frame to report complete to the master, once each: the next frame to present, when
    /// every tile of it is here. Call it after every tile and every present. A later frame that
    /// completes first is held back until it is next, so the master cannot start frames further
    /// ahead than this assembler accepts, whatever order tiles and presents arrive in.
    pub fn poll_complete(&mut self) -> Option<FrameId> {
        let next = self.next_present;
        if self.is_complete(next) && self.reported_complete != Some(next) {
            self.reported_complete = Some(next);
            return Some(next);
        }
        None
    }

    /// The master announced `frame` with `state`. Tiles of another state are refused from now
    /// on, and those already here are checked at the present.
    ///
    /// # Errors
    /// A frame already presented, or further ahead than frames are assembled.
    pub fn handle_frame_start(
        &mut self,
        frame: FrameId,
        state: StateId,
    ) -> Result<(), AssembleError> {
        self.check_frame(frame)?;
        self.states.insert(frame, state);
        Ok(())
    }

    /// Checks a tile header before its pixels are read; returns the expected byte length.
    pub fn check_tile(
        &self,
        frame: FrameId,
        tile: TileId,
        byte_len: usize,
    ) -> Result<usize, AssembleError> {
        let t = self.tile(tile)?;
        let expected = t.pixel_count() * 3;
        if byte_len != expected {
            return Err(AssembleError::WrongLength {
                tile: tile.0,
                expected,
                got: byte_len,
            });
        }
        self.check_frame(frame)?;
        Ok(expected)
    }

    fn check_frame(&self, frame: FrameId) -> Result<(), AssembleError> {
        if frame < self.next_present {
            return Err(AssembleError::Stale(frame));
        }
        if frame.0 >= self.next_present.0 + FRAMES_AHEAD {
            return Err(AssembleError::TooFarAhead {
                frame,
                next: self.next_present,
            });
        }
        Ok(())
    }

    fn tile(&self, tile: TileId) -> Result<&Tile, AssembleError> {
        tile.0
            .checked_sub(self.first_tile)
            .and_then(|i| self.tiles.get(i as usize))
            .ok_or(AssembleError::NotMine(tile.0))
    }

    /// Adds a tile; returns `Some(frame)` when this tile completed the frame.
    /// A tile that arrives twice (re-rendered after a node failure) is counted and ignored,
    /// also when its frame is already presented: after a node is given up for dead, its copy
    /// may complete the frame while a live node's copy is still on the way, and that late copy
    /// is no fault of the live node.
    pub fn handle_tile(
        &mut self,
        frame: FrameId,
        state: StateId,
        tile: TileId,
        rgb: &[u8],
    ) -> Result<Option<FrameId>, AssembleError> {
        match self.check_tile(frame, tile, rgb.len()) {
            Err(AssembleError::Stale(_)) => {
                self.duplicates += 1;
                return Ok(None);
            }
            checked => checked?,
        };
        let expected = self
            .states
            .get(&frame)
            .copied()
            .or_else(|| self.frames.get(&frame).map(|p| p.state));
        if let Some(expected) = expected.filter(|&e| e != state) {
            return Err(AssembleError::WrongState {
                frame,
                tile: tile.0,
                got: state,
                expected,
            });
        }
        let index = (tile.0 - self.first_tile) as usize;
        let t = self.tiles[index];
        let (sw, sh) = (self.screen.width as usize, self.screen.height as usize);
        let tile_count = self.tiles.len();
        let partial = self.frames.entry(frame).or_insert_with(|| Partial {
            image: vec![0; sw * sh * 3],
            have: vec![false; tile_count],
            missing: tile_count,
            state,
        });
        if partial.have[index] {
            self.duplicates += 1;
            return Ok(None);
        }
        partial.have[index] = true;
        partial.missing -= 1;
        let (x0, y0) = (
            (t.x - self.screen.x) as usize,
            (t.y - self.screen.y) as usize,
        );
        let row_bytes = t.width as usize * 3;
        for row in 0..t.height as usize {
            let dst = ((y0 + row) * sw + x0) * 3;
            partial.image[dst..dst + row_bytes]
                .copy_from_slice(&rgb[row * row_bytes..(row + 1) * row_bytes]);
        }
        Ok((partial.missing == 0).then_some(frame))
    }

    /// Frames up to `frame` were abandoned by the master: none of them is shown, what came of
    /// them is dropped, and the next frame to present is the one after.
    pub fn cancel_up_to(&mut self, frame: FrameId) {
        if frame < self.next_present {
            return;
        }
        self.next_present = FrameId(frame.0 + 1);
        self.frames.retain(|f, _| *f > frame);
        self.states.retain(|f, _| *f > frame);
    }

    /// The swap barrier: hands over `frame` for presentation. Frames are presented in order.
    pub fn handle_present(&mut self, frame: FrameId) -> Result<PresentedFrame, AssembleError> {
        if frame < self.next_present {
            return Err(AssembleError::Stale(frame));
        }
        let state = match self.frames.get(&frame) {
            Some(p) if p.missing == 0 => p.state,
            _ => return Err(AssembleError::Incomplete(frame)),
        };
        match self.states.get(&frame) {
            None => return Err(AssembleError::UnknownState(frame)),
            Some(&expected) if expected != state => {
                // Only the tiles that came before the frame start can disagree here; every
                // tile after it was checked on arrival.
                return Err(AssembleError::WrongState {
                    frame,
                    tile: self.first_tile,
                    got: state,
                    expected,
                });
            }
            Some(_) => {}
        }
        let partial = self.frames.remove(&frame).expect("checked above");
        self.next_present = FrameId(frame.0 + 1);
        self.frames.retain(|f, _| *f > frame);
        self.states.retain(|f, _| *f > frame);
        Ok(PresentedFrame {
            frame,
            width: self.screen.width,
            height: self.screen.height,
            rgb: partial.image,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_model::wall::{DisplayId, WallSpec};

    fn setup() -> (TileGrid, FrameAssembler) {
        let wall = WallSpec::grid(2, 1, 20, 10)
            .tile_size(8)
            .bezel(3)
            .build()
            .unwrap();
        let grid = TileGrid::new(wall.clone());
        let mut asm = FrameAssembler::new(&grid, wall.screen(DisplayId(1)).unwrap());
        for f in 0..FRAMES_AHEAD {
            asm.handle_frame_start(FrameId(f), S).unwrap();
        }
        (grid, asm)
    }

    /// The state every frame of these tests is announced with.
    const S: StateId = StateId(5);

    impl FrameAssembler {
        fn handle_tile_s(
            &mut self,
            frame: FrameId,
            tile: TileId,
            rgb: &[u8],
        ) -> Result<Option<FrameId>, AssembleError> {
            self.handle_tile(frame, S, tile, rgb)
        }
    }

    fn pixels(tile: &Tile, frame: u64) -> Vec<u8> {
        (0..tile.pixel_count() * 3)
            .map(|i| (i as u64 * 7 + tile.id.0 as u64 + frame) as u8)
            .collect()
    }

    #[test]
    fn frame_completes_after_its_last_tile_and_lands_where_it_belongs() {
        let (grid, mut asm) = setup();
        let mine = grid.display_tiles(DisplayId(1)).to_vec();
        for (i, t) in mine.iter().enumerate() {
            let done = asm.handle_tile_s(FrameId(0), t.id, &pixels(t, 0)).unwrap();
            assert_eq!(done.is_some(), i + 1 == mine.len());
        }
        let shown = asm.handle_present(FrameId(0)).unwrap();
        let screen_x = 23;
        for t in &mine {
            let p = pixels(t, 0);
            let (x, y) = ((t.x - screen_x) as usize, t.y as usize);
            let at = (y * 20 + x) * 3;
            assert_eq!(&shown.rgb[at..at + 3], &p[..3]);
        }
    }

    #[test]
    fn foreign_wrong_sized_and_early_tiles_are_refused_and_late_ones_counted() {
        let (grid, mut asm) = setup();
        let other = grid.display_tiles(DisplayId(0))[0];
        assert_eq!(
            asm.handle_tile_s(FrameId(0), other.id, &pixels(&other, 0)),
            Err(AssembleError::NotMine(other.id.0))
        );
        let t = grid.display_tiles(DisplayId(1))[0];
        assert!(matches!(
            asm.handle_tile_s(FrameId(0), t.id, &[0; 5]),
            Err(AssembleError::WrongLength { .. })
        ));
        assert!(matches!(
            asm.handle_tile_s(FrameId(FRAMES_AHEAD), t.id, &pixels(&t, 0)),
            Err(AssembleError::TooFarAhead { .. })
        ));
        assert_eq!(
            asm.handle_tile_s(FrameId(0), TileId(u32::MAX), &[]),
            Err(AssembleError::NotMine(u32::MAX))
        );
        assert_eq!(
            asm.handle_present(FrameId(0)).unwrap_err(),
            AssembleError::Incomplete(FrameId(0))
        );
        for t in grid.display_tiles(DisplayId(1)) {
            asm.handle_tile_s(FrameId(0), t.id, &pixels(t, 0)).unwrap();
        }
        asm.handle_present(FrameId(0)).unwrap();
        // A late copy of a presented frame's tile is a duplicate, not a fault; garbage is.
        assert_eq!(
            asm.handle_tile_s(FrameId(0), t.id, &pixels(&t, 0)),
            Ok(None)
        );
        assert_eq!(asm.duplicates(), 1);
        assert!(asm.handle_tile_s(FrameId(0), t.id, &[0; 5]).is_err());
    }

    #[test]
    fn duplicates_are_counted_not_double_counted() {
        let (grid, mut asm) = setup();
        let mine = grid.display_tiles(DisplayId(1)).to_vec();
        asm.handle_tile_s(FrameId(1), mine[0].id, &pixels(&mine[0], 1))
            .unwrap();
        asm.handle_tile_s(FrameId(1), mine[0].id, &pixels(&mine[0], 1))
            .unwrap();
        assert_eq!(asm.duplicates(), 1);
        let mut completed = None;
        for t in &mine[1..] {
            completed = asm.handle_tile_s(FrameId(1), t.id, &pixels(t, 1)).unwrap();
        }
        assert_eq!(completed, Some(FrameId(1)));
        assert!(asm.is_complete(FrameId(1)) && !asm.is_complete(FrameId(0)));
    }

    #[test]
    fn a_frame_is_reported_complete_once_and_only_when_it_is_next_to_present() {
        let (grid, mut asm) = setup();
        let mine = grid.display_tiles(DisplayId(1)).to_vec();
        let fill = |asm: &mut FrameAssembler, frame: u64| {
            for t in &mine {
                asm.handle_tile_s(FrameId(frame), t.id, &pixels(t, frame))
                    .unwrap();
            }
        };
        fill(&mut asm, 1);
        assert_eq!(asm.poll_complete(), None, "frame 1 waits for frame 0");
        fill(&mut asm, 0);
        assert_eq!(asm.poll_complete(), Some(FrameId(0)));
        assert_eq!(asm.poll_complete(), None, "reported once");
        asm.handle_present(FrameId(0)).unwrap();
        assert_eq!(asm.poll_complete(), Some(FrameId(1)));
        assert_eq!(asm.poll_complete(), None);
    }

    #[test]
    fn a_tile_of_another_state_than_its_frame_is_refused() {
        let (grid, mut asm) = setup();
        let mine = grid.display_tiles(DisplayId(1)).to_vec();
        let stale = StateId(4);
        assert_eq!(
            asm.handle_tile(FrameId(0), stale, mine[0].id, &pixels(&mine[0], 0)),
            Err(AssembleError::WrongState {
                frame: FrameId(0),
                tile: mine[0].id.0,
                got: stale,
                expected: S
            })
        );
        assert!(!asm.is_complete(FrameId(0)));
    }

    #[test]
    fn tiles_that_came_before_the_frame_start_are_checked_at_the_present() {
        let wall = WallSpec::grid(1, 1, 16, 8).tile_size(8).build().unwrap();
        let grid = TileGrid::new(wall.clone());
        let tiles = grid.display_tiles(DisplayId(0)).to_vec();
        let mut asm = FrameAssembler::new(&grid, wall.screen(DisplayId(0)).unwrap());
        // Both tiles of frame 0 arrive with state 1 before the master's frame start, which
        // says state 2: the frame mixes nothing among its tiles, but it is not frame 0.
        for t in &tiles {
            asm.handle_tile(FrameId(0), StateId(1), t.id, &pixels(t, 0))
                .unwrap();
        }
        assert_eq!(
            asm.handle_present(FrameId(0)).unwrap_err(),
            AssembleError::UnknownState(FrameId(0))
        );
        asm.handle_frame_start(FrameId(0), StateId(2)).unwrap();
        assert!(matches!(
            asm.handle_present(FrameId(0)),
            Err(AssembleError::WrongState { .. })
        ));
        // Two tiles that disagree with each other never make a frame either.
        let mut asm = FrameAssembler::new(&grid, wall.screen(DisplayId(0)).unwrap());
        asm.handle_tile(FrameId(0), StateId(1), tiles[0].id, &pixels(&tiles[0], 0))
            .unwrap();
        assert!(matches!(
            asm.handle_tile(FrameId(0), StateId(2), tiles[1].id, &pixels(&tiles[1], 0)),
            Err(AssembleError::WrongState { .. })
        ));
        assert!(!asm.is_complete(FrameId(0)));
    }
}
