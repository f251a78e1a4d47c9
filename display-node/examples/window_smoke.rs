//! Manual check for the window presenter: shows a known 320x200 test pattern.
//!
//! Usage: `window_smoke [--hold-ms N] [--png PATH]`. `--png` writes the pattern as a binary PPM
//! (P6), not PNG: display-node does not depend on `image`. Prints `presented 0` once the frame
//! has been on screen for ~1 s, which is the moment to take a screenshot.

use std::io::Write;
use std::sync::mpsc;
use std::time::Duration;

use anyhow::{bail, Context};
use tessera_display_node::window::{window_presenter, WindowCallbacks, WindowCommand, WindowFrame};

const WIDTH: u32 = 320;
const HEIGHT: u32 = 200;
const TITLE: &str = "tessera window_smoke";

/// Each quadrant has its own base colour plus x/y gradients, so flips, offsets, channel swaps and
/// scaling all show up as pixel differences.
fn pattern() -> Vec<u8> {
    let mut rgb = Vec::with_capacity((WIDTH * HEIGHT * 3) as usize);
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            let gx = (x * 255 / (WIDTH - 1)) as u8;
            let gy = (y * 255 / (HEIGHT - 1)) as u8;
            let px = match (x < WIDTH / 2, y < HEIGHT / 2) {
                (true, true) => [255, gx, gy],
                (false, true) => [gy, 255, gx],
                (true, false) => [gx, gy, 255],
                (false, false) => [gx ^ gy, 128, 255 - gx],
            };
            rgb.extend_from_slice(&px);
        }
    }
    rgb
}

fn write_ppm(path: &str, rgb: &[u8]) -> anyhow::Result<()> {
    let mut data = format!("P6\n{WIDTH} {HEIGHT}\n255\n").into_bytes();
    data.extend_from_slice(rgb);
    std::fs::write(path, data).with_context(|| format!("writing {path}"))
}

fn main() -> anyhow::Result<()> {
    let mut hold_ms = 3000u64;
    let mut out = None;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--hold-ms" => hold_ms = args.next().context("--hold-ms needs a value")?.parse()?,
            "--png" => out = Some(args.next().context("--png needs a path")?),
            _ => bail!("usage: window_smoke [--hold-ms N] [--png PATH]"),
        }
    }
    let rgb = pattern();
    if let Some(path) = &out {
        write_ppm(path, &rgb)?;
    }

    let (presented_tx, presented_rx) = mpsc::channel();
    let (sender, runner) = window_presenter(
        TITLE.to_owned(),
        (WIDTH, HEIGHT),
        Default::default(),
        WindowCallbacks {
            on_presented: Box::new(move |frame| {
                let _ = presented_tx.send(frame);
            }),
            on_input: Box::new(|_| {}),
        },
    )?;
    let frame = WindowFrame {
        frame: 0,
        width: WIDTH,
        height: HEIGHT,
        overlay: None,
        status: None,
        rgb,
    };
    sender.send(WindowCommand::Show(frame));

    let control = std::thread::spawn(move || {
        let presented = presented_rx.recv_timeout(Duration::from_secs(10));
        if let Ok(frame) = presented {
            std::thread::sleep(Duration::from_secs(1));
            println!("presented {frame}");
            let _ = std::io::stdout().flush();
            std::thread::sleep(Duration::from_millis(hold_ms));
        }
        sender.send(WindowCommand::Close);
        presented.is_ok()
    });
    runner.run()?;
    if !control.join().expect("control thread panicked") {
        bail!("frame 0 was not presented within 10 s");
    }
    Ok(())
}
