//! The crate's error type.

/// Errors raised by `ferroslam-features` constructors on invalid input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FeaturesError {
    /// The scale pyramid needs a finite scale factor > 1 and at least one level.
    #[error(
        "invalid scale pyramid (scale_factor = {scale_factor}, n_levels = {n_levels}): \
         use a finite scale factor > 1 (ORB-SLAM uses 1.2) and n_levels >= 1 (ORB-SLAM uses 8)"
    )]
    InvalidPyramid {
        /// The rejected scale factor.
        scale_factor: f64,
        /// The rejected number of levels.
        n_levels: usize,
    },
    /// An image buffer does not hold `width * height` bytes, or the image is empty.
    #[error("invalid image: {width}x{height} needs {} bytes, got {len}", width.saturating_mul(*height))]
    InvalidImage {
        /// Claimed width, pixels.
        width: usize,
        /// Claimed height, pixels.
        height: usize,
        /// Buffer length, bytes.
        len: usize,
    },
    /// An ORB extractor setting is out of range (the message names it and its valid range).
    #[error("invalid ORB extractor configuration: {0}")]
    InvalidOrbConfig(String),
    /// An image is too small for the pyramid asked of it.
    #[error(
        "image {width}x{height} is too small for {n_levels} pyramid levels of scale \
         {scale_factor}: level {level} would be {level_width}x{level_height} px; use fewer \
         levels or a smaller scale factor"
    )]
    ImageTooSmall {
        /// Image width, pixels.
        width: usize,
        /// Image height, pixels.
        height: usize,
        /// Levels asked for.
        n_levels: usize,
        /// Scale between neighbouring levels.
        scale_factor: f64,
        /// The first level without pixels.
        level: usize,
        /// Its width, pixels.
        level_width: usize,
        /// Its height, pixels.
        level_height: usize,
    },
    /// A keypoint mask is not the size of its image.
    #[error(
        "the mask is {mask_width}x{mask_height} (width x height) but the image is \
         {image_width}x{image_height}: give a mask of the image's size (0 = no keypoint there)"
    )]
    MaskSizeMismatch {
        /// Mask width, pixels.
        mask_width: usize,
        /// Mask height, pixels.
        mask_height: usize,
        /// Image width, pixels.
        image_width: usize,
        /// Image height, pixels.
        image_height: usize,
    },
    /// A mask cannot be built from the parameters given (the message names the parameter).
    #[error("invalid mask: {0}")]
    InvalidMask(String),
}
