//! The image files of a dataset, read and written with errors naming the file: every photo and
//! mask is opened as a regular file ([`mipnerf_core::io::open_regular`]: a FIFO or a device given as a
//! photo is refused by name), a JPEG cut short is refused, and a PNG is encoded in memory and
//! written whole ([`mipnerf_core::io::write_encoded`]).

use std::path::Path;

use crate::DataError;

/// Reads a PNG as straight RGBA8, with errors naming the file.
pub(crate) fn read_png_rgba(path: &Path) -> Result<(u32, u32, Vec<u8>, u8), DataError> {
    let reader = image_reader(path)?;
    if reader.format() == Some(image::ImageFormat::Jpeg) {
        check_jpeg_end(path)?;
    }
    let img = reader.decode().map_err(|e| DataError::invalid(path, format!("cannot decode the image: {e}")))?;
    let channels = img.color().channel_count();
    let rgba = img.to_rgba8();
    Ok((rgba.width(), rgba.height(), rgba.into_raw(), channels))
}

/// Refuses a file that is missing (saying `missing`) or not a regular file (saying what it is:
/// a FIFO, a device, a folder), naming it.
pub(crate) fn check_present(file: &Path, missing: &str) -> Result<(), DataError> {
    match mipnerf_core::io::check_regular(file) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(DataError::invalid(file, missing)),
        Err(e) => Err(DataError::io(file, e)),
    }
}

/// The size of the image `path` from its header, without decoding it.
pub(crate) fn image_size(path: &Path) -> Result<(u32, u32), DataError> {
    image_reader(path)?
        .into_dimensions()
        .map_err(|e| DataError::invalid(path, format!("cannot decode the image (reading its size): {e}")))
}

/// An image decoder over the regular file `path` ([`mipnerf_core::io::open_regular`]: a FIFO or a
/// device given as a photo is refused by name, never waited on or read without end), its format
/// guessed from its first bytes.
fn image_reader(path: &Path) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>, DataError> {
    let file = mipnerf_core::io::open_regular(path).map_err(|e| DataError::io(path, e))?;
    image::ImageReader::new(std::io::BufReader::new(file)).with_guessed_format().map_err(|e| DataError::io(path, e))
}

/// Refuses a JPEG cut short: the decoder fills what is missing with grey and says nothing, so a
/// file must end with its end-of-image marker (`FF D9`; trailing zero bytes allowed), as every
/// camera and encoder writes it.
fn check_jpeg_end(path: &Path) -> Result<(), DataError> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = mipnerf_core::io::open_regular(path).map_err(|e| DataError::io(path, e))?;
    let len = f.metadata().map_err(|e| DataError::io(path, e))?.len();
    let mut tail = vec![0u8; len.min(4096) as usize];
    f.seek(SeekFrom::Start(len - tail.len() as u64))
        .and_then(|_| f.read_exact(&mut tail))
        .map_err(|e| DataError::io(path, e))?;
    let end = tail.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    if end < 2 || tail[end - 2..end] != [0xFF, 0xD9] {
        return Err(DataError::invalid(
            path,
            "the JPEG is cut short (no end-of-image marker): the file was not copied whole; copy it again",
        ));
    }
    Ok(())
}

/// The pixel count of an image from its header, without decoding it.
pub(crate) fn image_pixels(path: &Path) -> Result<u64, DataError> {
    let (w, h) = image_size(path)?;
    Ok(u64::from(w) * u64::from(h))
}

/// Writes straight RGBA8 as a PNG, whole or not at all ([`mipnerf_core::io::replace_with`]).
pub(crate) fn write_png_rgba(path: &Path, width: u32, height: u32, rgba: &[u8]) -> Result<(), DataError> {
    mipnerf_core::io::write_encoded(path, |bytes| {
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(bytes),
            rgba,
            width,
            height,
            image::ExtendedColorType::Rgba8,
        )
        .map_err(|e| DataError::invalid(path, format!("cannot write the PNG: {e}")))
    })
}
