//! Decoding the images of textures, whether a scene's files or a glTF model's, within the
//! texture budget.

use tessera_description::limits;

/// Decodes an image within the texture budget: its size is read from the header and
/// refused past `limits::MAX_TEXTURE_PIXELS`, and the decoder itself may allocate no more
/// than such an image needs (16 bytes a pixel: 32-bit float RGBA), so that a small file
/// declaring a huge image is an error, never a multi-gigabyte allocation or a panic.
pub(crate) fn decode_image(bytes: &[u8]) -> image::ImageResult<image::DynamicImage> {
    use image::error::{LimitError, LimitErrorKind};
    let reader = || image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format();
    let (width, height) = reader()?.into_dimensions()?;
    if u64::from(width) * u64::from(height) > limits::MAX_TEXTURE_PIXELS {
        return Err(image::ImageError::Limits(LimitError::from_kind(LimitErrorKind::DimensionError)));
    }
    let mut budget = image::Limits::default();
    budget.max_image_width = Some(limits::MAX_SIDE);
    budget.max_image_height = Some(limits::MAX_SIDE);
    budget.max_alloc = Some(limits::MAX_TEXTURE_PIXELS * 16);
    let mut reader = reader()?;
    reader.limits(budget);
    reader.decode()
}
