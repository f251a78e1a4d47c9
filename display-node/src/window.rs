//! Window presenter for one screen of the wall (winit 0.30 + softbuffer 0.4), and the person
//! in front of it: keys, drags and the wheel go back to the master as input events.
//!
//! A window of the screen's own size gets each frame pixel for pixel (no scaling, no gamma),
//! so a screenshot of its inner area equals the RGB frame byte for byte; a window of another
//! size (`--window-size`, full screen) shows it scaled to fit, nearest pixel.

use std::collections::BTreeSet;
use std::num::NonZeroU32;
use std::rc::Rc;

use crate::overlay::{self, FrameStatus, Overlay};
use anyhow::{anyhow, bail, Context as _};
use tessera_model::input::{Button, InputEvent, Key};
use tessera_model::window::WindowPlacement;
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop, EventLoopProxy};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Fullscreen, Window, WindowId};

/// One frame to show: `rgb` is width*height*3 bytes, RGB8, row-major, row 0 at the top.
pub struct WindowFrame {
    /// The frame's number, handed back to `on_presented` once it is on screen.
    pub frame: u64,
    /// Pixels across; a frame not of the window's screen size is dropped with a warning.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// The pixels, as above.
    pub rgb: Vec<u8>,
    /// Drawn over the frame when the overlay is on.
    pub overlay: Option<Overlay>,
    /// The frame's state and quality: the status line, with the key help or the overlay.
    pub status: Option<FrameStatus>,
}

/// Messages from the (tokio) network side to the window.
pub enum WindowCommand {
    /// Present this frame at the next redraw (a later one before then replaces it).
    Show(WindowFrame),
    /// Close the window and end [`WindowRunner::run`].
    Close,
}

/// Thread-safe handle for sending commands to the window's event loop.
#[derive(Clone)]
pub struct WindowSender {
    proxy: EventLoopProxy<WindowCommand>,
}

impl WindowSender {
    /// Returns false if the event loop is gone (window closed or runner dropped).
    pub fn send(&self, cmd: WindowCommand) -> bool {
        self.proxy.send_event(cmd).is_ok()
    }
}

/// Owns the event loop; `run` must be called on the thread that created it (the main thread).
pub struct WindowRunner {
    event_loop: EventLoop<WindowCommand>,
    app: App,
}

/// What the window reports back: each frame once presented, and the person's input.
pub struct WindowCallbacks {
    /// Called on the main thread right after a frame has been handed to softbuffer's
    /// `present()` (once per frame; re-presents after expose do not count).
    pub on_presented: Box<dyn FnMut(u64) + Send>,
    /// Called on the main thread for each key, drag and wheel turn.
    pub on_input: Box<dyn FnMut(InputEvent) + Send>,
}

/// Creates the event loop (must be called on the main thread). Returns a sender usable from any
/// thread, and a runner to call on the main thread that blocks until the window is closed or
/// Close is sent. Frames are `width × height`; `placement` says where the window goes.
pub fn window_presenter(
    title: String,
    (width, height): (u32, u32),
    placement: WindowPlacement,
    callbacks: WindowCallbacks,
) -> anyhow::Result<(WindowSender, WindowRunner)> {
    let (nz_width, nz_height) = match (NonZeroU32::new(width), NonZeroU32::new(height)) {
        (Some(w), Some(h)) => (w, h),
        _ => bail!("window size must be non-zero, got {width}x{height}"),
    };
    // winit panics (rather than erroring) when the loop is built off the main thread; Rust always
    // names the main thread "main", so this turns that panic into an error in the common case.
    if std::thread::current().name() != Some("main") {
        bail!("window_presenter must be called on the main thread");
    }
    let event_loop = EventLoop::<WindowCommand>::with_user_event()
        .build()
        .map_err(|e| anyhow!("{}: {e}", no_display_message()))?;
    let sender = WindowSender {
        proxy: event_loop.create_proxy(),
    };
    let app = App {
        title,
        width: nz_width,
        height: nz_height,
        placement,
        callbacks,
        state: None,
        frame: None,
        reported: None,
        error: None,
        buttons: BTreeSet::new(),
        cursor: None,
        dragged: false,
        help: false,
    };
    Ok((sender, WindowRunner { event_loop, app }))
}

impl WindowRunner {
    /// Blocks until Close is sent or the user closes the window (both return Ok).
    pub fn run(mut self) -> anyhow::Result<()> {
        self.event_loop
            .run_app(&mut self.app)
            .context("window event loop failed")?;
        match self.app.error.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

fn no_display_message() -> String {
    let var = |name| std::env::var(name).unwrap_or_else(|_| "<unset>".to_owned());
    format!(
        "cannot open a window (is a display server running? DISPLAY={}, WAYLAND_DISPLAY={})",
        var("DISPLAY"),
        var("WAYLAND_DISPLAY")
    )
}

struct Surface {
    window: Rc<Window>,
    surface: softbuffer::Surface<Rc<Window>, Rc<Window>>,
    /// The window's inner size, which the buffer follows.
    size: (NonZeroU32, NonZeroU32),
}

struct App {
    title: String,
    /// The frames' size: the screen's resolution.
    width: NonZeroU32,
    height: NonZeroU32,
    placement: WindowPlacement,
    callbacks: WindowCallbacks,
    state: Option<Surface>,
    /// Last accepted frame, kept so expose events can re-present it.
    frame: Option<WindowFrame>,
    /// Last frame number passed to `on_presented`, so re-presents are not reported twice.
    reported: Option<u64>,
    /// Errors inside callbacks cannot be returned from winit; stash them for `run`.
    error: Option<anyhow::Error>,
    /// Mouse buttons held, and where the cursor last was (to turn moves into drags).
    buttons: BTreeSet<Button>,
    cursor: Option<(f64, f64)>,
    /// Whether the cursor moved while a button was held: a release then ends a drag, not a
    /// click.
    dragged: bool,
    /// Whether this window shows its key help (`?` or F1 toggles it, here only).
    help: bool,
}

impl App {
    fn create_surface(&self, event_loop: &ActiveEventLoop) -> anyhow::Result<Surface> {
        let (w, h) = self
            .placement
            .size
            .unwrap_or((self.width.get(), self.height.get()));
        let size = PhysicalSize::new(w, h);
        let mut attrs = Window::default_attributes()
            .with_title(self.title.clone())
            .with_inner_size(size)
            .with_min_inner_size(size)
            .with_max_inner_size(size)
            .with_resizable(false);
        if let Some((x, y)) = self.placement.position {
            attrs = attrs.with_position(PhysicalPosition::new(x, y));
        }
        if let Some(n) = self.placement.fullscreen {
            let monitors: Vec<_> = event_loop.available_monitors().collect();
            let monitor = monitors.get(n as usize).cloned().with_context(|| {
                format!(
                    "--fullscreen {n}: this display server has {} monitor(s)",
                    monitors.len()
                )
            })?;
            // Placed and sized as the monitor too: a bare X session (a wall's usual set-up)
            // has no window manager to carry out the full-screen request.
            attrs = attrs
                .with_position(monitor.position())
                .with_inner_size(monitor.size())
                .with_min_inner_size(monitor.size())
                .with_max_inner_size(monitor.size())
                .with_decorations(false)
                .with_fullscreen(Some(Fullscreen::Borderless(Some(monitor))));
        }
        let window = Rc::new(
            event_loop
                .create_window(attrs)
                .map_err(|e| anyhow!("{}: {e}", no_display_message()))?,
        );
        let context = softbuffer::Context::new(window.clone())
            .map_err(|e| anyhow!("softbuffer context: {e}"))?;
        let mut surface = softbuffer::Surface::new(&context, window.clone())
            .map_err(|e| anyhow!("softbuffer surface: {e}"))?;
        let inner = window.inner_size();
        let size = (
            NonZeroU32::new(inner.width).unwrap_or(self.width),
            NonZeroU32::new(inner.height).unwrap_or(self.height),
        );
        surface
            .resize(size.0, size.1)
            .map_err(|e| anyhow!("softbuffer resize: {e}"))?;
        Ok(Surface {
            window,
            surface,
            size,
        })
    }

    fn resized(&mut self, size: PhysicalSize<u32>) -> anyhow::Result<()> {
        let (Some(state), Some(w), Some(h)) = (
            self.state.as_mut(),
            NonZeroU32::new(size.width),
            NonZeroU32::new(size.height),
        ) else {
            return Ok(());
        };
        state.size = (w, h);
        state
            .surface
            .resize(w, h)
            .map_err(|e| anyhow!("softbuffer resize: {e}"))?;
        state.window.request_redraw();
        Ok(())
    }

    fn redraw(&mut self) -> anyhow::Result<()> {
        let Some(state) = self.state.as_mut() else {
            return Ok(());
        };
        let mut buffer = state
            .surface
            .buffer_mut()
            .map_err(|e| anyhow!("softbuffer buffer: {e}"))?;
        match &self.frame {
            Some(f) => {
                let overlaid;
                let rgb = if f.overlay.is_some() || self.help {
                    let mut copy = f.rgb.clone();
                    if let Some(o) = &f.overlay {
                        overlay::draw(&mut copy, f.width, f.height, o);
                    }
                    if self.help {
                        overlay::draw_help(&mut copy, f.width, f.height, f.status.as_ref());
                    }
                    overlaid = copy;
                    &overlaid
                } else {
                    &f.rgb
                };
                let (bw, bh) = (state.size.0.get(), state.size.1.get());
                if (bw, bh) == (f.width, f.height) {
                    for (px, rgb) in buffer.iter_mut().zip(rgb.chunks_exact(3)) {
                        *px = pack(rgb);
                    }
                } else {
                    scale_into(&mut buffer, (bw, bh), rgb, (f.width, f.height));
                }
            }
            None => buffer.fill(0),
        }
        state.window.pre_present_notify();
        buffer
            .present()
            .map_err(|e| anyhow!("softbuffer present: {e}"))?;
        if let Some(f) = &self.frame {
            if self.reported != Some(f.frame) {
                self.reported = Some(f.frame);
                (self.callbacks.on_presented)(f.frame);
            }
        }
        Ok(())
    }

    /// Turns a window event into an input event for the master, if it is one.
    fn input(&mut self, event: &WindowEvent) -> Option<InputEvent> {
        let (screen_width, screen_height) = self
            .state
            .as_ref()
            .map_or((self.width.get() as f64, self.height.get() as f64), |s| {
                (s.size.0.get() as f64, s.size.1.get() as f64)
            });
        match event {
            WindowEvent::KeyboardInput { event, .. } => {
                let PhysicalKey::Code(code) = event.physical_key else {
                    return None;
                };
                Some(InputEvent::Key {
                    key: key_of(code)?,
                    pressed: event.state == ElementState::Pressed,
                })
            }
            WindowEvent::MouseInput { state, button, .. } => {
                let button = button_of(*button)?;
                if *state == ElementState::Pressed {
                    if self.buttons.is_empty() {
                        self.dragged = false;
                    }
                    self.buttons.insert(button);
                    return None;
                }
                self.buttons.remove(&button);
                // Released where it was pressed: a click, at its place on the screen.
                let (x, y) = self.cursor?;
                (!self.dragged && self.buttons.is_empty()).then(|| InputEvent::Click {
                    button,
                    fx: (x / screen_width).clamp(0.0, 1.0) as f32,
                    fy: (y / screen_height).clamp(0.0, 1.0) as f32,
                })
            }
            WindowEvent::CursorMoved { position, .. } => {
                let now = (position.x, position.y);
                let last = self.cursor.replace(now)?;
                let button = *self.buttons.iter().next()?;
                self.dragged |= now != last;
                let (dx, dy) = (
                    (now.0 - last.0) / screen_height,
                    (now.1 - last.1) / screen_height,
                );
                (dx != 0.0 || dy != 0.0).then_some(InputEvent::Drag {
                    button,
                    dx: dx as f32,
                    dy: dy as f32,
                })
            }
            WindowEvent::CursorLeft { .. } => {
                self.cursor = None;
                None
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => *y,
                    // A trackpad's pixels: call a line 40 of them.
                    MouseScrollDelta::PixelDelta(p) => (p.y / 40.0) as f32,
                };
                (lines != 0.0).then_some(InputEvent::Scroll {
                    lines: lines.clamp(
                        -tessera_model::input::MAX_MOVE,
                        tessera_model::input::MAX_MOVE,
                    ),
                })
            }
            _ => None,
        }
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, err: anyhow::Error) {
        self.error.get_or_insert(err);
        event_loop.exit();
    }
}

impl ApplicationHandler<WindowCommand> for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        // Resumed can fire more than once on some platforms; one window is enough.
        if self.state.is_some() {
            return;
        }
        match self.create_surface(event_loop) {
            Ok(state) => {
                state.window.request_redraw();
                self.state = Some(state);
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn user_event(&mut self, event_loop: &ActiveEventLoop, cmd: WindowCommand) {
        match cmd {
            WindowCommand::Close => event_loop.exit(),
            WindowCommand::Show(f) => {
                let expected = self.width.get() as usize * self.height.get() as usize * 3;
                if f.width != self.width.get()
                    || f.height != self.height.get()
                    || f.rgb.len() != expected
                {
                    tracing::warn!(
                        frame = f.frame,
                        "ignoring frame of {}x{} ({} bytes); window is {}x{}",
                        f.width,
                        f.height,
                        f.rgb.len(),
                        self.width,
                        self.height
                    );
                    return;
                }
                self.frame = Some(f);
                // Redraws are coalesced by winit, so a burst of Shows presents only the latest.
                if let Some(state) = &self.state {
                    state.window.request_redraw();
                }
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        if is_help_key(&event) {
            self.help = !self.help;
            if let Some(state) = &self.state {
                state.window.request_redraw();
            }
            return;
        }
        if let Some(input) = self.input(&event) {
            (self.callbacks.on_input)(input);
        }
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.fail(event_loop, e);
                }
            }
            WindowEvent::Resized(size) => {
                if let Err(e) = self.resized(size) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn exiting(&mut self, _event_loop: &ActiveEventLoop) {
        // Drop the surface before the loop tears down the display connection.
        self.state = None;
    }
}

/// `?` (the slash key, shifted or not) or F1 pressed: the key help's toggle, which stays in
/// this window.
fn is_help_key(event: &WindowEvent) -> bool {
    let WindowEvent::KeyboardInput { event, .. } = event else {
        return false;
    };
    event.state == ElementState::Pressed
        && !event.repeat
        && matches!(
            event.physical_key,
            PhysicalKey::Code(KeyCode::F1 | KeyCode::Slash)
        )
}

fn pack(rgb: &[u8]) -> u32 {
    (u32::from(rgb[0]) << 16) | (u32::from(rgb[1]) << 8) | u32::from(rgb[2])
}

/// Nearest-pixel scaling of an RGB8 frame into a window buffer of another size.
fn scale_into(buffer: &mut [u32], (bw, bh): (u32, u32), rgb: &[u8], (fw, fh): (u32, u32)) {
    for y in 0..bh {
        let sy = (y as u64 * fh as u64 / bh as u64) as u32;
        for x in 0..bw {
            let sx = (x as u64 * fw as u64 / bw as u64) as u32;
            let i = ((sy * fw + sx) * 3) as usize;
            buffer[(y * bw + x) as usize] = pack(&rgb[i..i + 3]);
        }
    }
}

fn key_of(code: KeyCode) -> Option<Key> {
    Some(match code {
        KeyCode::KeyW => Key::W,
        KeyCode::KeyA => Key::A,
        KeyCode::KeyS => Key::S,
        KeyCode::KeyD => Key::D,
        KeyCode::KeyQ => Key::Q,
        KeyCode::KeyE => Key::E,
        KeyCode::KeyF => Key::F,
        KeyCode::KeyH | KeyCode::Home => Key::H,
        KeyCode::KeyO => Key::O,
        KeyCode::Digit1 => Key::Digit1,
        KeyCode::Digit2 => Key::Digit2,
        KeyCode::Digit3 => Key::Digit3,
        KeyCode::KeyZ => Key::Z,
        _ => return None,
    })
}

fn button_of(button: MouseButton) -> Option<Button> {
    match button {
        MouseButton::Left => Some(Button::Left),
        MouseButton::Right => Some(Button::Right),
        MouseButton::Middle => Some(Button::Middle),
        _ => None,
    }
}
