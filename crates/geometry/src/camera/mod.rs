//! Camera models. One model per file; each states its projection, its valid domain and
//! which pixels (ideal or distorted) it works on.

mod pinhole;

pub use pinhole::{test_cameras, ImageBounds, PinholeCamera, RadTan};
