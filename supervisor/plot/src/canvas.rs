//! One drawing backend for both outputs: each figure is drawn twice, into an SVG file and into
//! the PNG's pixel buffer, by the same chart code. plotters' chart code is generic over the
//! backend; behind one enum it is compiled once, not once per backend (half the crate's build).
//! Every call goes to the backend inside, so the files are those the backends draw alone.

use plotters::prelude::{BitMapBackend, DrawingBackend, SVGBackend};
use plotters_backend::{
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind,
};

/// An SVG file or an RGB pixel buffer.
pub enum Canvas<'a> {
    Svg(SVGBackend<'a>),
    Bitmap(BitMapBackend<'a>),
}

/// What went wrong in the backend inside (an SVG file's I/O, or the pixel buffer's).
#[derive(Debug)]
pub struct CanvasError(Box<dyn std::error::Error + Send + Sync>);

impl std::fmt::Display for CanvasError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl std::error::Error for CanvasError {}

type Res<T = ()> = Result<T, DrawingErrorKind<CanvasError>>;

fn lift<E: std::error::Error + Send + Sync + 'static>(
    e: DrawingErrorKind<E>,
) -> DrawingErrorKind<CanvasError> {
    match e {
        DrawingErrorKind::DrawingError(e) => DrawingErrorKind::DrawingError(CanvasError(e.into())),
        DrawingErrorKind::FontError(f) => DrawingErrorKind::FontError(f),
    }
}

/// Runs `$call` on the backend inside, its error lifted.
macro_rules! each {
    ($self:ident, $b:ident => $call:expr) => {
        match $self {
            Canvas::Svg($b) => $call.map_err(lift),
            Canvas::Bitmap($b) => $call.map_err(lift),
        }
    };
}

impl DrawingBackend for Canvas<'_> {
    type ErrorType = CanvasError;

    fn get_size(&self) -> (u32, u32) {
        match self {
            Canvas::Svg(b) => b.get_size(),
            Canvas::Bitmap(b) => b.get_size(),
        }
    }

    fn ensure_prepared(&mut self) -> Res {
        each!(self, b => b.ensure_prepared())
    }

    fn present(&mut self) -> Res {
        each!(self, b => b.present())
    }

    fn draw_pixel(&mut self, point: BackendCoord, color: BackendColor) -> Res {
        each!(self, b => b.draw_pixel(point, color))
    }

    fn draw_line<S: BackendStyle>(&mut self, from: BackendCoord, to: BackendCoord, s: &S) -> Res {
        each!(self, b => b.draw_line(from, to, s))
    }

    fn draw_rect<S: BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        s: &S,
        fill: bool,
    ) -> Res {
        each!(self, b => b.draw_rect(upper_left, bottom_right, s, fill))
    }

    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        s: &S,
    ) -> Res {
        each!(self, b => b.draw_path(path, s))
    }

    fn draw_circle<S: BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        s: &S,
        fill: bool,
    ) -> Res {
        each!(self, b => b.draw_circle(center, radius, s, fill))
    }

    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        s: &S,
    ) -> Res {
        each!(self, b => b.fill_polygon(vert, s))
    }

    fn draw_text<T: BackendTextStyle>(&mut self, text: &str, s: &T, pos: BackendCoord) -> Res {
        each!(self, b => b.draw_text(text, s, pos))
    }

    fn estimate_text_size<T: BackendTextStyle>(&self, text: &str, s: &T) -> Res<(u32, u32)> {
        each!(self, b => b.estimate_text_size(text, s))
    }

    fn blit_bitmap(&mut self, pos: BackendCoord, size: (u32, u32), src: &[u8]) -> Res {
        each!(self, b => b.blit_bitmap(pos, size, src))
    }
}
