//! Window presenter for one screen of the wall (winit 0.30 + softbuffer 0.4).
//!
//! Frames are copied into the softbuffer buffer pixel for pixel (no scaling, no gamma), so a
//! screenshot of the window's inner area equals the RGB frame byte for byte.

use std::num::NonZeroU32;
use std::rc::Rc;

use anyhow::{anyhow, bail, Context as _};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, EventLoop, EventLoopProxy};
use winit::window::{Window, WindowId};

/// One frame to show: `rgb` is width*height*3 bytes, RGB8, row-major, row 0 at the top.
pub struct WindowFrame {
    pub frame: u64,
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Messages from the (tokio) network side to the window.
pub enum WindowCommand {
    Show(WindowFrame),
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

/// Creates the event loop (must be called on the main thread). Returns a sender usable from any
/// thread, and a runner to call on the main thread that blocks until the window is closed or
/// Close is sent. `on_presented(frame)` is called on the main thread right after each frame has
/// been handed to softbuffer's `present()` (once per frame; re-presents after expose do not count).
pub fn window_presenter(
    title: String,
    width: u32,
    height: u32,
    on_presented: Box<dyn FnMut(u64) + Send>,
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
        on_presented,
        state: None,
        frame: None,
        reported: None,
        error: None,
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
}

struct App {
    title: String,
    width: NonZeroU32,
    height: NonZeroU32,
    on_presented: Box<dyn FnMut(u64) + Send>,
    state: Option<Surface>,
    /// Last accepted frame, kept so expose events can re-present it.
    frame: Option<WindowFrame>,
    /// Last frame number passed to `on_presented`, so re-presents are not reported twice.
    reported: Option<u64>,
    /// Errors inside callbacks cannot be returned from winit; stash them for `run`.
    error: Option<anyhow::Error>,
}

impl App {
    fn create_surface(&self, event_loop: &ActiveEventLoop) -> anyhow::Result<Surface> {
        let size = PhysicalSize::new(self.width.get(), self.height.get());
        let attrs = Window::default_attributes()
            .with_title(self.title.clone())
            .with_inner_size(size)
            .with_min_inner_size(size)
            .with_max_inner_size(size)
            .with_resizable(false);
        let window = Rc::new(
            event_loop
                .create_window(attrs)
                .map_err(|e| anyhow!("{}: {e}", no_display_message()))?,
        );
        let context = softbuffer::Context::new(window.clone())
            .map_err(|e| anyhow!("softbuffer context: {e}"))?;
        let mut surface = softbuffer::Surface::new(&context, window.clone())
            .map_err(|e| anyhow!("softbuffer surface: {e}"))?;
        surface
            .resize(self.width, self.height)
            .map_err(|e| anyhow!("softbuffer resize: {e}"))?;
        Ok(Surface { window, surface })
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
                for (px, rgb) in buffer.iter_mut().zip(f.rgb.chunks_exact(3)) {
                    *px = (u32::from(rgb[0]) << 16) | (u32::from(rgb[1]) << 8) | u32::from(rgb[2]);
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
                (self.on_presented)(f.frame);
            }
        }
        Ok(())
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
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
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
