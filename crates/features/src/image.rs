//! 8-bit grayscale images (one pyramid level each), row-major without padding: borrowed
//! ([`GrayImage`]) and owned ([`OwnedGrayImage`]).

use crate::error::FeaturesError;

/// A borrowed `height x width` 8-bit grayscale image; pixel `(x, y)` is `data[y * width + x]`.
#[derive(Clone, Copy, Debug)]
pub struct GrayImage<'a> {
    width: usize,
    height: usize,
    data: &'a [u8],
}

impl<'a> GrayImage<'a> {
    /// Wraps `data` (row-major, `width * height` bytes).
    ///
    /// # Errors
    /// [`FeaturesError::InvalidImage`] when the buffer length is not `width * height` or the
    /// image is empty.
    pub fn new(width: usize, height: usize, data: &'a [u8]) -> Result<Self, FeaturesError> {
        if width == 0 || height == 0 || width.checked_mul(height) != Some(data.len()) {
            return Err(FeaturesError::InvalidImage {
                width,
                height,
                len: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// All pixels, row-major (`pixels()[y * width + x]`).
    pub fn pixels(&self) -> &'a [u8] {
        self.data
    }

    /// Row `y` from column `x0` on, `len` pixels; `None` when any of it lies outside.
    pub fn row_span(&self, x0: isize, y: isize, len: usize) -> Option<&'a [u8]> {
        if x0 < 0 || y < 0 || y as usize >= self.height || x0 as usize + len > self.width {
            return None;
        }
        let start = y as usize * self.width + x0 as usize;
        Some(&self.data[start..start + len])
    }
}

/// An owned `height x width` 8-bit grayscale image; [`OwnedGrayImage::view`] borrows it as a
/// [`GrayImage`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OwnedGrayImage {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl OwnedGrayImage {
    /// Takes `data` (row-major, `width * height` bytes).
    ///
    /// # Errors
    /// As [`GrayImage::new`].
    pub fn new(width: usize, height: usize, data: Vec<u8>) -> Result<Self, FeaturesError> {
        GrayImage::new(width, height, &data)?;
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// The image, borrowed (its size: `view().width()`, `view().height()`).
    pub fn view(&self) -> GrayImage<'_> {
        GrayImage {
            width: self.width,
            height: self.height,
            data: &self.data,
        }
    }

    /// The pixels, row-major (`[y * width + x]`).
    pub fn into_pixels(self) -> Vec<u8> {
        self.data
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_wrong_buffer_length() {
        assert!(GrayImage::new(4, 3, &[0; 11]).is_err());
        assert!(GrayImage::new(0, 0, &[]).is_err());
        assert!(GrayImage::new(4, 3, &[0; 12]).is_ok());
        assert!(OwnedGrayImage::new(4, 3, vec![0; 11]).is_err());
        let owned = OwnedGrayImage::new(4, 3, (0..12).collect()).unwrap();
        assert_eq!(owned.view().row_span(1, 2, 3), Some(&[9, 10, 11][..]));
    }

    #[test]
    fn row_span_is_bounds_checked() {
        let data: Vec<u8> = (0..12).collect();
        let img = GrayImage::new(4, 3, &data).unwrap();
        assert_eq!(img.row_span(1, 2, 3), Some(&data[9..12]));
        assert_eq!(img.row_span(2, 2, 3), None);
        assert_eq!(img.row_span(-1, 0, 2), None);
        assert_eq!(img.row_span(0, 3, 1), None);
    }
}
