//! Camera models. One model per file; each states its projection, its valid domain and
//! which pixels (ideal or distorted) it works on. [`CameraModel`] is the one type the
//! core tracks with.

mod kannala_brandt;
mod model;
mod pinhole;
mod validation;

pub use kannala_brandt::{test_fisheye_cameras, KannalaBrandtCamera};
pub use model::CameraModel;
pub use pinhole::{test_cameras, ImageBounds, PinholeCamera, RadTan};
