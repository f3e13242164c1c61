//! A small RGB raster: rectangles, lines, text in an embedded font (pre-rasterised Noto Sans
//! Mono, anti-aliased), PNG encoding. Enough to draw a report without a plotting library or a
//! font on the machine.

use noto_sans_mono_bitmap::{get_raster, get_raster_width, FontWeight, RasterHeight};

/// An sRGB colour.
pub(crate) type Rgb = [u8; 3];

/// Text sizes (line heights in pixels).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Size {
    /// 16 px lines (about 12 px type): labels, tables.
    Small,
    /// 20 px lines: body text, numbers.
    Body,
    /// 24 px lines: titles, the verdict.
    Title,
}

impl Size {
    fn raster(self) -> RasterHeight {
        match self {
            Size::Small => RasterHeight::Size16,
            Size::Body => RasterHeight::Size20,
            Size::Title => RasterHeight::Size24,
        }
    }

    /// Advance of one character (the font is monospaced), px.
    pub(crate) fn advance(self) -> usize {
        get_raster_width(FontWeight::Regular, self.raster())
    }
}

/// Characters outside the embedded font (Basic Latin and Latin-1), written with ones inside.
fn fallback(c: char) -> Option<&'static str> {
    Some(match c {
        '—' | '–' | '−' => "-",
        '≤' => "<=",
        '≥' => ">=",
        '≈' => "~",
        'σ' => "sigma",
        '…' => "...",
        '‘' | '’' => "'",
        '“' | '”' => "\"",
        '→' => "->",
        '·' => "*",
        '²' => "2",
        'Δ' => "d",
        _ => return None,
    })
}

/// `text` with every character the font lacks replaced.
pub(crate) fn printable(text: &str) -> String {
    let mut s = String::with_capacity(text.len());
    for c in text.chars() {
        if get_raster(c, FontWeight::Regular, RasterHeight::Size16).is_some() {
            s.push(c);
        } else if let Some(r) = fallback(c) {
            s.push_str(r);
        } else if c.is_whitespace() {
            s.push(' ');
        } else {
            s.push('?');
        }
    }
    s
}

/// Splits `text` into lines of at most `max_chars` characters at spaces (a longer word is cut).
pub(crate) fn wrap(text: &str, max_chars: usize) -> Vec<String> {
    let max_chars = max_chars.max(8);
    let mut lines = Vec::new();
    let mut line = String::new();
    for word in printable(text).split(' ') {
        let mut word = word.to_string();
        while word.chars().count() > max_chars {
            if !line.is_empty() {
                lines.push(std::mem::take(&mut line));
            }
            let head: String = word.chars().take(max_chars).collect();
            word = word.chars().skip(max_chars).collect();
            lines.push(head);
        }
        let needed = line.chars().count() + usize::from(!line.is_empty()) + word.chars().count();
        if needed > max_chars && !line.is_empty() {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(&word);
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines
}

/// An RGB image, row-major, origin top left.
#[derive(Debug, Clone)]
pub(crate) struct Canvas {
    pub(crate) width: usize,
    pub(crate) height: usize,
    pixels: Vec<Rgb>,
}

impl Canvas {
    /// A `width`×`height` image filled with `background`.
    pub(crate) fn new(width: usize, height: usize, background: Rgb) -> Canvas {
        Canvas {
            width,
            height,
            pixels: vec![background; width * height],
        }
    }

    /// Sets one pixel (ignored outside the image).
    #[inline]
    pub(crate) fn set(&mut self, x: i64, y: i64, c: Rgb) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.pixels[y as usize * self.width + x as usize] = c;
        }
    }

    /// Blends `c` over one pixel with opacity `alpha` (0–255).
    #[inline]
    pub(crate) fn blend(&mut self, x: i64, y: i64, c: Rgb, alpha: u8) {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return;
        }
        let p = &mut self.pixels[y as usize * self.width + x as usize];
        let a = u32::from(alpha);
        for k in 0..3 {
            p[k] = ((u32::from(c[k]) * a + u32::from(p[k]) * (255 - a) + 127) / 255) as u8;
        }
    }

    /// A filled rectangle.
    pub(crate) fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        for yy in y.max(0)..(y + h).min(self.height as i64) {
            for xx in x.max(0)..(x + w).min(self.width as i64) {
                self.pixels[yy as usize * self.width + xx as usize] = c;
            }
        }
    }

    /// A one-pixel rectangle outline.
    pub(crate) fn stroke_rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        self.line(x, y, x + w - 1, y, c);
        self.line(x, y + h - 1, x + w - 1, y + h - 1, c);
        self.line(x, y, x, y + h - 1, c);
        self.line(x + w - 1, y, x + w - 1, y + h - 1, c);
    }

    /// A one-pixel line (Bresenham).
    pub(crate) fn line(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: Rgb) {
        self.dashed(x0, y0, x1, y1, c, 0);
    }

    /// A one-pixel line drawn `dash` pixels on, `dash` off (`dash` 0: solid).
    pub(crate) fn dashed(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: Rgb, dash: i64) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        let mut k = 0i64;
        loop {
            if dash == 0 || (k / dash) % 2 == 0 {
                self.set(x, y, c);
            }
            k += 1;
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Draws `text` with its top-left corner at (x, y); returns the x after it.
    pub(crate) fn text(
        &mut self,
        x: i64,
        y: i64,
        text: &str,
        size: Size,
        bold: bool,
        c: Rgb,
    ) -> i64 {
        let weight = if bold {
            FontWeight::Bold
        } else {
            FontWeight::Regular
        };
        let mut cx = x;
        for ch in printable(text).chars() {
            let glyph = get_raster(ch, weight, size.raster())
                .or_else(|| get_raster('?', weight, size.raster()));
            if let Some(g) = glyph {
                for (gy, row) in g.rows().enumerate() {
                    for (gx, &a) in row.iter().enumerate() {
                        if a > 0 {
                            self.blend(cx + gx as i64, y + gy as i64, c, a);
                        }
                    }
                }
            }
            cx += size.advance() as i64;
        }
        cx
    }

    /// Width of `text` in pixels.
    pub(crate) fn text_width(text: &str, size: Size) -> i64 {
        (printable(text).chars().count() * size.advance()) as i64
    }

    /// Draws `text` right-aligned so that it ends at `x_right`.
    pub(crate) fn text_right(&mut self, x_right: i64, y: i64, text: &str, size: Size, c: Rgb) {
        let w = Self::text_width(text, size);
        self.text(x_right - w, y, text, size, false, c);
    }

    /// Copies `src` with its top-left corner at (x, y).
    pub(crate) fn blit(&mut self, x: i64, y: i64, src: &Canvas) {
        for sy in 0..src.height {
            for sx in 0..src.width {
                self.set(
                    x + sx as i64,
                    y + sy as i64,
                    src.pixels[sy * src.width + sx],
                );
            }
        }
    }

    /// The image as an 8-bit RGB PNG.
    pub(crate) fn png(&self) -> Result<Vec<u8>, png::EncodingError> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width as u32, self.height as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Balanced);
            let mut writer = enc.write_header()?;
            let bytes: Vec<u8> = self.pixels.iter().flatten().copied().collect();
            writer.write_image_data(&bytes)?;
            writer.finish()?;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_and_wrapped() {
        let mut c = Canvas::new(200, 40, [255, 255, 255]);
        let end = c.text(2, 2, "x 12.3 mm 0.5°", Size::Body, false, [0, 0, 0]);
        assert_eq!(end, 2 + 14 * Size::Body.advance() as i64);
        let dark = c.pixels.iter().filter(|p| p[0] < 128).count();
        assert!(dark > 50, "{dark} dark pixels");
        assert_eq!(printable("≤ 2σ — ok"), "<= 2sigma - ok");
        assert_eq!(
            wrap("the robot was not found in the scan at all", 16),
            ["the robot was", "not found in the", "scan at all"]
        );
        assert_eq!(
            wrap("abcdefghijklmnopqrstu", 8),
            ["abcdefgh", "ijklmnop", "qrstu"]
        );
    }

    #[test]
    fn png_round_trips() {
        let mut c = Canvas::new(7, 5, [10, 20, 30]);
        c.set(3, 2, [200, 100, 50]);
        let bytes = c.png().expect("encodes");
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = dec.read_info().expect("header");
        let mut buf = vec![0; reader.output_buffer_size().expect("size")];
        let info = reader.next_frame(&mut buf).expect("frame");
        assert_eq!((info.width, info.height), (7, 5));
        assert_eq!(&buf[(2 * 7 + 3) * 3..(2 * 7 + 3) * 3 + 3], &[200, 100, 50]);
        assert_eq!(&buf[0..3], &[10, 20, 30]);
    }
}
