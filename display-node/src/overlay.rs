//! What a window draws over its frame, never into the frame itself (snapshots and the wall's
//! pixels stay exact):
//!
//! - the overlay, on request (`O`, wall-wide): over every tile a tint in the colour of the
//!   render node that drew it with the milliseconds the tile took, the status line, and
//!   where the scene has particles the legend of their colour map (`legend.rs`);
//! - the key help (`?` or F1, this window only): every key and drag the windows take, and the
//!   status line;
//! - the status line: the frame's state id, the display's frame rate and frame time, and the
//!   quality knobs the frame was rendered with.
//!
//! It needs no scene data: who sent each tile and how long it took travel in the pixel stream's
//! header, the state, quality and colour map in the frame's start, the particles' range in
//! the session. Text is the public-domain 8x8 font of
//! the `font8x8` crate, doubled on screens wide enough to read it from a step back.

// What to draw is the display session's (it times the presents and knows who rendered each
// tile); drawing it is the window's.
pub use tessera_core::node::display::{FrameStatus, Overlay, TileInfo};

/// What the key help lists: the keys and drags every window takes (the master's navigator,
/// `tessera_core::master::navigate`, and this window's own `?`).
pub const KEY_HELP: &[&str] = &[
    "KEYS (this help: ? or F1)",
    "drag          orbit about the scene",
    "right drag    pan     wheel  zoom",
    "F             fly mode: W A S D, Q E",
    "Z             fit the scene to the view",
    "H or Home     home view",
    "1             shadows on/off",
    "2             AO rays 0/4/16",
    "3             samples per pixel 1/2/4/8",
    "O             overlay: nodes and tiles",
    "click         probe a volume",
];

/// The status line of a frame: its state, this display's rate, its quality.
pub fn status_line(status: Option<&FrameStatus>, fps: f32, frame_ms: f32) -> String {
    let rate = format!("{fps:.1} fps {frame_ms:.1} ms");
    match status {
        Some(s) => format!(
            "state {}  {rate}  {} spp  AO {}  shadows {}",
            s.state.0,
            s.spp,
            s.ao_samples,
            if s.shadows { "on" } else { "off" }
        ),
        None => rate,
    }
}

/// A distinct, stable colour per render node (hues spread by the golden angle).
pub fn node_colour(node: u32) -> [u8; 3] {
    let hue = (node as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - (hue % 2.0 - 1.0).abs();
    let (r, g, b) = match hue as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    [(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]
}

/// Draws `overlay` into an RGB8 image of `width × height`.
pub fn draw(rgb: &mut [u8], width: u32, height: u32, overlay: &Overlay) {
    for t in &overlay.tiles {
        let colour = node_colour(t.node);
        for y in t.y..(t.y + t.height).min(height) {
            for x in t.x..(t.x + t.width).min(width) {
                let i = ((y * width + x) * 3) as usize;
                let edge = x == t.x || y == t.y;
                for c in 0..3 {
                    let tinted = if edge {
                        colour[c]
                    } else {
                        ((rgb[i + c] as u16 * 2 + colour[c] as u16) / 3) as u8
                    };
                    rgb[i + c] = tinted;
                }
            }
        }
        text(
            rgb,
            width,
            height,
            t.x + 3,
            t.y + 3,
            &format!("{:.1}", t.ms),
        );
    }
    if let (Some(range), Some(s)) = (overlay.particles, &overlay.status) {
        crate::legend::draw_legend(rgb, (width, height), s.colormap, range, s.crop);
    }
    let label = status_line(overlay.status.as_ref(), overlay.fps, overlay.frame_ms);
    bottom_line(rgb, width, height, &label);
}

/// Draws the key help and the status line into an RGB8 image of `width × height`.
pub fn draw_help(rgb: &mut [u8], width: u32, height: u32, status: Option<&FrameStatus>) {
    let scale = scale_for(width);
    let line = (LINE + 2) * scale;
    for (i, text_line) in KEY_HELP.iter().enumerate() {
        text(rgb, width, height, 8, 8 + i as u32 * line, text_line);
    }
    if let Some(s) = status {
        bottom_line(rgb, width, height, &status_line(Some(s), 0.0, 0.0));
    }
}

/// Glyph cell side, in pixels before scaling.
pub(crate) const LINE: u32 = 9;

/// Text is doubled on screens wider than this, to be read from a step back.
const DOUBLE_ABOVE: u32 = 1200;

/// Pixels per glyph pixel on a screen `width` pixels across.
pub(crate) fn scale_for(width: u32) -> u32 {
    if width > DOUBLE_ABOVE {
        2
    } else {
        1
    }
}

fn bottom_line(rgb: &mut [u8], width: u32, height: u32, s: &str) {
    let y = height.saturating_sub((LINE + 3) * scale_for(width));
    text(rgb, width, height, 4, y, s);
}

/// How wide [`text`] draws `s` on a screen `width` pixels across, its box included.
pub(crate) fn text_width(s: &str, width: u32) -> u32 {
    (s.chars().count() as u32 * 8 + 2) * scale_for(width)
}

/// Writes `s` (ASCII; anything else is a blank) in white on a black box with its top-left
/// corner at `(x, y)`, clipped, each glyph pixel `scale_for(width)` pixels square.
pub(crate) fn text(rgb: &mut [u8], width: u32, height: u32, x: u32, y: u32, s: &str) {
    let scale = scale_for(width);
    let glyphs: Vec<[u8; 8]> = s
        .chars()
        .map(|c| {
            let code = c as usize;
            font8x8::legacy::BASIC_LEGACY
                .get(code)
                .copied()
                .unwrap_or([0; 8])
        })
        .collect();
    let (w, h) = (text_width(s, width), LINE * scale);
    for py in y..(y + h).min(height) {
        for px in x..(x + w).min(width) {
            let (col, row) = ((px - x) / scale, (py - y) / scale);
            let lit = col >= 1 && (1..=8).contains(&row) && {
                let (cell, bit) = ((col - 1) / 8, (col - 1) % 8);
                glyphs
                    .get(cell as usize)
                    .is_some_and(|g| g[(row - 1) as usize] & (1 << bit) != 0)
            };
            let v = if lit { 255 } else { 0 };
            let i = ((py * width + px) * 3) as usize;
            rgb[i..i + 3].copy_from_slice(&[v, v, v]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_are_tinted_by_node_and_the_rest_is_left_alone() {
        let (w, h) = (64u32, 32u32);
        let mut rgb = vec![100u8; (w * h * 3) as usize];
        let overlay = Overlay {
            fps: 30.0,
            frame_ms: 33.3,
            tiles: vec![TileInfo {
                x: 32,
                y: 0,
                width: 32,
                height: 16,
                node: 1,
                ms: 2.5,
            }],
            status: None,
            particles: Some([0.0, 1.0]),
        };
        draw(&mut rgb, w, h, &overlay);
        let at = |x: u32, y: u32| &rgb[((y * w + x) * 3) as usize..((y * w + x) * 3 + 3) as usize];
        // Inside the tile, away from its text and edge, the node's colour shows through.
        let c = node_colour(1);
        let tint = |v: u8, c: u8| ((v as u16 * 2 + c as u16) / 3) as u8;
        assert_eq!(
            at(60, 14),
            &[tint(100, c[0]), tint(100, c[1]), tint(100, c[2])]
        );
        assert_eq!(at(10, 5), &[100, 100, 100], "outside every tile");
        assert_ne!(node_colour(0), node_colour(1));
    }

    #[test]
    fn the_status_line_names_state_rate_and_quality_and_the_help_every_key() {
        let params = tessera_model::params::RenderParams::interactive();
        let status = FrameStatus::of(tessera_model::state::StateId(12), &params);
        let line = status_line(Some(&status), 29.96, 33.4);
        assert!(
            line.starts_with("state 12  30.0 fps 33.4 ms  1 spp  AO 0"),
            "{line}"
        );
        for key in ["? or F1", "Z ", "H or Home", "F ", "O ", "1 ", "2 ", "3 "] {
            assert!(
                KEY_HELP.iter().any(|l| l.contains(key)),
                "{key} missing from the help"
            );
        }
        // The help is drawn: white glyph pixels on black boxes, only where its lines go.
        let (w, h) = (400u32, 200u32);
        let mut rgb = vec![100u8; (w * h * 3) as usize];
        draw_help(&mut rgb, w, h, Some(&status));
        let lit = rgb
            .chunks_exact(3)
            .filter(|p| p == &[255, 255, 255])
            .count();
        assert!(lit > 500, "{lit} lit pixels");
        let right_edge = ((100 * w + w - 1) * 3) as usize;
        assert_eq!(rgb[right_edge], 100, "the frame shows beside the help");
    }

    #[test]
    fn the_overlay_draws_the_particles_legend_only_where_the_scene_has_particles() {
        let (w, h) = (240u32, 120u32);
        let params = tessera_model::params::RenderParamsSpec {
            colormap: tessera_model::colormap::ColorMap::Coolwarm,
            ..tessera_model::params::RenderParamsSpec::INTERACTIVE
        }
        .build()
        .unwrap();
        let status = FrameStatus::of(tessera_model::state::StateId(3), &params);
        let drawn = |particles| {
            let mut rgb = vec![100u8; (w * h * 3) as usize];
            let overlay = Overlay {
                status: Some(status),
                particles,
                ..Overlay::default()
            };
            draw(&mut rgb, w, h, &overlay);
            rgb
        };
        let bar = crate::legend::bar(w);
        let i = (((bar.y + 2) * w + bar.x) * 3) as usize;
        let blue = drawn(Some([1.0, 2.0]));
        assert!(
            blue[i + 2] > blue[i],
            "coolwarm starts blue: {:?}",
            &blue[i..i + 3]
        );
        assert_eq!(
            &drawn(None)[i..i + 3],
            &[100, 100, 100],
            "no particles, no legend"
        );
    }
}
