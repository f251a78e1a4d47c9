//! The overlay a display draws over its frame on request: its own frame rate and frame time,
//! and over every tile a tint in the colour of the render node that drew it with the
//! milliseconds the tile took. It needs no scene data: who sent each tile and how long it
//! took travel in the pixel stream's header.

// What to draw is the display session's (it times the presents and knows who rendered each
// tile); drawing it is the window's.
pub use tessera_core::node::display::{Overlay, TileInfo};

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
    let label = format!("{:.1} FPS {:.1} MS", overlay.fps, overlay.frame_ms);
    text(rgb, width, height, 4, height.saturating_sub(12), &label);
}

/// 5×7 glyphs of what the overlay writes: digits, a point and a few capitals.
fn glyph(c: char) -> [u8; 7] {
    match c {
        '0' => [0x0e, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0e],
        '1' => [0x04, 0x0c, 0x04, 0x04, 0x04, 0x04, 0x0e],
        '2' => [0x0e, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1f],
        '3' => [0x1f, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0e],
        '4' => [0x02, 0x06, 0x0a, 0x12, 0x1f, 0x02, 0x02],
        '5' => [0x1f, 0x10, 0x1e, 0x01, 0x01, 0x11, 0x0e],
        '6' => [0x06, 0x08, 0x10, 0x1e, 0x11, 0x11, 0x0e],
        '7' => [0x1f, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0e, 0x11, 0x11, 0x0e, 0x11, 0x11, 0x0e],
        '9' => [0x0e, 0x11, 0x11, 0x0f, 0x01, 0x02, 0x0c],
        '.' => [0, 0, 0, 0, 0, 0x0c, 0x0c],
        'F' => [0x1f, 0x10, 0x10, 0x1e, 0x10, 0x10, 0x10],
        'P' => [0x1e, 0x11, 0x11, 0x1e, 0x10, 0x10, 0x10],
        'S' => [0x0f, 0x10, 0x10, 0x0e, 0x01, 0x01, 0x1e],
        'M' => [0x11, 0x1b, 0x15, 0x15, 0x11, 0x11, 0x11],
        _ => [0; 7],
    }
}

/// Writes `s` in white on a black box with its top-left corner at `(x, y)`, clipped.
fn text(rgb: &mut [u8], width: u32, height: u32, x: u32, y: u32, s: &str) {
    let (w, h) = (s.chars().count() as u32 * 6 + 1, 9);
    for py in y..(y + h).min(height) {
        for px in x..(x + w).min(width) {
            let i = ((py * width + px) * 3) as usize;
            let (col, row) = (px - x, py - y);
            let lit = col >= 1 && (1..=7).contains(&row) && {
                let (cell, bit) = ((col - 1) / 6, (col - 1) % 6);
                let c = s.chars().nth(cell as usize).unwrap_or(' ');
                bit < 5 && glyph(c)[(row - 1) as usize] & (0x10 >> bit) != 0
            };
            let v = if lit { 255 } else { 0 };
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
}
