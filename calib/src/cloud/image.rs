//! The colour (or intensity) image a camera gives registered to its depth: pixel `(u, v)` of
//! the image is pixel `(u, v)` of the organized scan. Read from 8- or 16-bit PNG (grey, grey
//! with alpha, RGB, RGBA; 16-bit samples keep their high byte).

use std::path::Path;

use super::CloudError;

/// Largest image read, pixels (a 12-megapixel camera; every frame's image is held in memory).
const MAX_IMAGE_PIXELS: usize = 4096 * 3072;

/// An 8-bit colour image, row-major, three channels per pixel (a grey image has three equal
/// channels).
#[derive(Debug, Clone, PartialEq)]
pub struct ColorImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `[r, g, b]` per pixel, row-major.
    pub rgb: Vec<[u8; 3]>,
}

impl ColorImage {
    /// The pixel at `(u, v)`, `None` outside the image.
    pub fn at(&self, u: i64, v: i64) -> Option<[u8; 3]> {
        if u < 0 || v < 0 || u as usize >= self.width || v as usize >= self.height {
            return None;
        }
        self.rgb.get(v as usize * self.width + u as usize).copied()
    }
}

/// Reads a PNG image (see the module docs).
pub fn read_png(path: &Path) -> Result<ColorImage, CloudError> {
    let bad = |reason: String| CloudError::Image {
        path: path.to_path_buf(),
        reason,
    };
    handeye_hal::limits::check_regular_file(path, 256 << 20)
        .map_err(|e| CloudError::io("open", path, e))?;
    let file = std::fs::File::open(path).map_err(|e| CloudError::io("open", path, e))?;
    let decoder = png::Decoder::new(std::io::BufReader::new(file));
    let mut reader = decoder.read_info().map_err(|e| bad(e.to_string()))?;
    let (width, height) = {
        let info = reader.info();
        (info.width as usize, info.height as usize)
    };
    if width * height > MAX_IMAGE_PIXELS {
        return Err(bad(format!(
            "{width}×{height} pixels: at most {MAX_IMAGE_PIXELS}"
        )));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| bad("the image is too large".into()))?;
    let mut buf = vec![0; size];
    let frame = reader
        .next_frame(&mut buf)
        .map_err(|e| bad(e.to_string()))?;
    let bytes_per_sample = match frame.bit_depth {
        png::BitDepth::Eight => 1,
        png::BitDepth::Sixteen => 2,
        d => return Err(bad(format!("{d:?}-bit samples: give an 8- or 16-bit PNG"))),
    };
    let channels = match frame.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => {
            return Err(bad(
                "an indexed (palette) PNG: give an RGB or grey PNG".into()
            ))
        }
    };
    let stride = frame.line_size;
    let sample = |row: &[u8], u: usize, c: usize| row[(u * channels + c) * bytes_per_sample];
    let mut rgb = Vec::with_capacity(width * height);
    for v in 0..height {
        let row = &buf[v * stride..(v + 1) * stride];
        for u in 0..width {
            rgb.push(if channels < 3 {
                let g = sample(row, u, 0);
                [g, g, g]
            } else {
                [sample(row, u, 0), sample(row, u, 1), sample(row, u, 2)]
            });
        }
    }
    Ok(ColorImage { width, height, rgb })
}

/// Writes `image` as an 8-bit RGB PNG (what [`read_png`] reads back pixel for pixel).
pub fn write_png(path: &Path, image: &ColorImage) -> Result<(), CloudError> {
    let bad = |reason: String| CloudError::Image {
        path: path.to_path_buf(),
        reason,
    };
    let (Ok(w), Ok(h)) = (u32::try_from(image.width), u32::try_from(image.height)) else {
        return Err(bad("too large for a PNG".into()));
    };
    let file = std::fs::File::create(path).map_err(|e| CloudError::io("create", path, e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let data: Vec<u8> = image.rgb.iter().flatten().copied().collect();
    enc.write_header()
        .and_then(|mut writer| writer.write_image_data(&data))
        .map_err(|e| bad(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What is written reads back pixel for pixel.
    #[test]
    fn a_written_png_reads_back() {
        let dir = std::env::temp_dir().join(format!("handeye-image-w-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let image = ColorImage {
            width: 4,
            height: 3,
            rgb: (0..12u8).map(|k| [k, 2 * k, 255 - k]).collect(),
        };
        let path = dir.join("w.png");
        write_png(&path, &image).expect("written");
        assert_eq!(read_png(&path).expect("reads"), image);
        std::fs::remove_dir_all(&dir).ok();
    }

    /// An RGB and a 16-bit grey PNG written here read back pixel for pixel.
    #[test]
    fn rgb_and_grey_png_read_back() {
        let dir = std::env::temp_dir().join(format!("handeye-image-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let write = |name: &str, color: png::ColorType, depth: png::BitDepth, data: &[u8]| {
            let path = dir.join(name);
            let file = std::fs::File::create(&path).expect("create");
            let mut enc = png::Encoder::new(file, 3, 2);
            enc.set_color(color);
            enc.set_depth(depth);
            enc.write_header()
                .expect("header")
                .write_image_data(data)
                .expect("data");
            path
        };
        let rgb: Vec<u8> = (0..18).map(|k| k * 10).collect();
        let img = read_png(&write(
            "rgb.png",
            png::ColorType::Rgb,
            png::BitDepth::Eight,
            &rgb,
        ))
        .expect("rgb reads");
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.at(1, 1), Some([120, 130, 140]));
        assert_eq!(img.at(3, 0), None);
        let grey: Vec<u8> = (0..6u8).flat_map(|k| [k * 40, 7]).collect();
        let img = read_png(&write(
            "grey.png",
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &grey,
        ))
        .expect("grey reads");
        assert_eq!(img.at(2, 1), Some([200, 200, 200]));
        std::fs::remove_dir_all(&dir).ok();
    }
}
