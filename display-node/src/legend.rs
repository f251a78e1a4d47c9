//! The particles' colour legend the overlay draws in the top-right corner: the frame's colour
//! map's name, a bar of its colours from the lowest attribute to the highest, and the two
//! ends as numbers. Where the frame crops the particles, the crop is named and the bar's
//! values outside it are dimmed (those particles are not drawn).

use crate::overlay::{scale_for, text, text_width, LINE};
use tessera_model::colormap::ColorMap;

/// Where the legend's bar lies on a screen: its top-left corner and size, in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Bar {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

/// Pixels between the legend and the screen's edges.
const MARGIN: u32 = 4;

/// The bar on a screen `width` pixels across: below the name's line, at most 128 pixels
/// wide (doubled with the text), never wider than the screen allows.
pub(crate) fn bar(width: u32) -> Bar {
    let scale = scale_for(width);
    let bar_width = (128 * scale).min(width.saturating_sub(2 * MARGIN)).max(1);
    Bar {
        x: width.saturating_sub(bar_width + MARGIN),
        y: MARGIN + (LINE + 1) * scale,
        width: bar_width,
        height: 8 * scale,
    }
}

/// The legend's title (the map's name, and the crop if any) and its two end labels.
pub(crate) fn labels(
    map: ColorMap,
    [lo, hi]: [f32; 2],
    crop: Option<(f32, f32)>,
) -> (String, String, String) {
    let title = match crop {
        Some((a, b)) => format!("{}  shown {}..{}", map.name(), number(a), number(b)),
        None => map.name().to_string(),
    };
    (title, number(lo), number(hi))
}

/// Draws the legend of `map` over the attribute range `[lo, hi]`, `crop` being the frame's,
/// into an RGB8 image of `width × height`.
pub(crate) fn draw_legend(
    rgb: &mut [u8],
    (width, height): (u32, u32),
    map: ColorMap,
    range: [f32; 2],
    crop: Option<(f32, f32)>,
) {
    let b = bar(width);
    let [lo, hi] = range;
    for i in 0..b.width {
        // As the render nodes map an attribute: its place in [lo, hi]; a single value is
        // the map's middle.
        let t = if hi > lo && b.width > 1 {
            i as f32 / (b.width - 1) as f32
        } else {
            0.5
        };
        let value = lo + (hi - lo) * t;
        let hidden = crop.is_some_and(|(a, z)| !(a..=z).contains(&value));
        let colour = map.eval(t).map(|c| {
            let v = encode_channel(c);
            if hidden {
                v / 3
            } else {
                v
            }
        });
        for y in b.y..(b.y + b.height).min(height) {
            let p = ((y * width + b.x + i) * 3) as usize;
            rgb[p..p + 3].copy_from_slice(&colour);
        }
    }
    let (title, low, high) = labels(map, range, crop);
    let right = |s: &str| width.saturating_sub(text_width(s, width) + MARGIN);
    text(rgb, width, height, right(&title), MARGIN, &title);
    let below = b.y + b.height + scale_for(width);
    text(rgb, width, height, b.x, below, &low);
    text(rgb, width, height, right(&high), below, &high);
}

/// A number short enough for the legend: up to three decimals, trailing zeros dropped, and
/// scientific notation for the very large and the very small.
fn number(v: f32) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-2..1e5).contains(&a) {
        return format!("{v:.2e}");
    }
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

/// Linear to 8 bits as the render nodes encode pixels (`tessera_render::encode_channel`, a
/// gamma of 2), so that the bar's colours are those of the particles under a white light.
/// Repeated here because displays do not depend on the renderer.
fn encode_channel(c: f32) -> u8 {
    if c.is_finite() {
        (c.clamp(0.0, 1.0).sqrt() * 255.0 + 0.5) as u8
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encoded(map: ColorMap, t: f32) -> [u8; 3] {
        map.eval(t).map(encode_channel)
    }

    fn at(rgb: &[u8], width: u32, x: u32, y: u32) -> [u8; 3] {
        let i = ((y * width + x) * 3) as usize;
        [rgb[i], rgb[i + 1], rgb[i + 2]]
    }

    /// White text pixels in the rectangle from `(x, y)`, `w × h`.
    fn lit(rgb: &[u8], width: u32, (x, y, w, h): (u32, u32, u32, u32)) -> usize {
        (y..y + h)
            .flat_map(|py| (x..x + w).map(move |px| (px, py)))
            .filter(|&(px, py)| at(rgb, width, px, py) == [255, 255, 255])
            .count()
    }

    #[test]
    fn the_legend_bar_runs_from_the_maps_low_colour_to_its_high_one_with_labels() {
        let (w, h) = (240u32, 100u32);
        for map in ColorMap::ALL {
            let mut rgb = vec![100u8; (w * h * 3) as usize];
            draw_legend(&mut rgb, (w, h), map, [-3.0, 7.5], None);
            let b = bar(w);
            let middle = b.y + b.height / 2;
            assert_eq!(at(&rgb, w, b.x, middle), encoded(map, 0.0), "{map:?}");
            assert_eq!(
                at(&rgb, w, b.x + b.width - 1, middle),
                encoded(map, 1.0),
                "{map:?}"
            );
            assert_ne!(encoded(map, 0.0), encoded(map, 1.0));
            // The title above the bar, the ends under its two ends.
            let below = b.y + b.height + 1;
            assert!(lit(&rgb, w, (b.x, 0, b.width, b.y)) > 10, "{map:?} title");
            assert!(lit(&rgb, w, (b.x, below, 24, LINE)) > 5, "{map:?} low end");
            let right = (b.x + b.width - 24, below, 24, LINE);
            assert!(lit(&rgb, w, right) > 5, "{map:?} high end");
            assert_eq!(
                at(&rgb, w, 4, 50),
                [100, 100, 100],
                "the frame shows beside it"
            );
        }
    }

    #[test]
    fn the_labels_name_the_map_the_ends_and_the_crop() {
        let (title, lo, hi) = labels(ColorMap::Magma, [-3.0, 7.5], None);
        assert_eq!(
            (title.as_str(), lo.as_str(), hi.as_str()),
            ("magma", "-3", "7.5")
        );
        let (title, lo, hi) = labels(ColorMap::Greys, [0.000_01, 2.5e6], Some((0.25, 1.0)));
        assert_eq!(title, "greys  shown 0.25..1");
        assert_eq!((lo.as_str(), hi.as_str()), ("1.00e-5", "2.50e6"));
    }

    #[test]
    fn values_the_crop_hides_are_dimmed_on_the_bar() {
        let (w, h) = (240u32, 60u32);
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        draw_legend(
            &mut rgb,
            (w, h),
            ColorMap::Greys,
            [0.0, 1.0],
            Some((0.5, 1.0)),
        );
        let b = bar(w);
        let y = b.y + 1;
        let right = at(&rgb, w, b.x + b.width - 1, y);
        assert_eq!(right, encoded(ColorMap::Greys, 1.0), "shown: as the map");
        let left_of_half = at(&rgb, w, b.x + b.width / 2 - 2, y);
        let t = (b.width / 2 - 2) as f32 / (b.width - 1) as f32;
        assert_eq!(left_of_half, encoded(ColorMap::Greys, t).map(|v| v / 3));
    }
}
