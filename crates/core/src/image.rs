//! Single-channel linear f32 images.

/// A single-channel image of linear intensities, row-major: pixel `(col, row)` is
/// `data[row * width + col]` and has its centre at image coordinates `(col, row)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Image {
    /// A black image.
    pub fn zeros(width: usize, height: usize) -> Self {
        Image { width, height, data: vec![0.0; width * height] }
    }

    /// Wraps `data`; panics if its length is not `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width * height, "Image::from_vec: {width}x{height} needs {} values", width * height);
        Image { width, height, data }
    }

    pub fn get(&self, col: usize, row: usize) -> f32 {
        self.data[row * self.width + col]
    }

    pub fn set(&mut self, col: usize, row: usize, value: f32) {
        self.data[row * self.width + col] = value;
    }

    /// Smallest and largest values, ignoring nothing: a NaN anywhere makes both NaN.
    pub fn min_max(&self) -> (f32, f32) {
        self.data.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            if v.is_nan() || lo.is_nan() {
                (f32::NAN, f32::NAN)
            } else {
                (lo.min(v), hi.max(v))
            }
        })
    }

    /// The position `(col, row)` of the first non-finite pixel, if any.
    pub fn first_non_finite(&self) -> Option<(usize, usize)> {
        self.data.iter().position(|v| !v.is_finite()).map(|i| (i % self.width, i / self.width))
    }

    /// Sum of all pixel values, accumulated in f64.
    pub fn sum(&self) -> f64 {
        self.data.iter().map(|&v| v as f64).sum()
    }
}
