//! OpenEXR output of a transient: one single-channel (`Y`, float32) image of width
//! `T` (time, left to right) and one row per measurement, rows in the order of the
//! `.npy` layout (`iy * sx + ix`, or `((ly * lx + …) …)` for exhaustive). Reshaping
//! the image to the `.npy` shape gives the same array.

use crate::error::{Error, Result};
use crate::transport::Transient;
use std::path::Path;

pub fn write(path: &Path, t: &Transient) -> Result<()> {
    let width = t.bins();
    let height = t.data.len() / width.max(1);
    let channel = exr::image::AnyChannel::new("Y", exr::image::FlatSamples::F32(t.data.clone()));
    let layer = exr::image::Layer::new(
        (width, height),
        exr::meta::header::LayerAttributes::named("transient"),
        exr::image::Encoding::SMALL_LOSSLESS,
        exr::image::AnyChannels::sort(smallvec_one(channel)),
    );
    let image = exr::image::Image::from_layer(layer);
    use exr::prelude::WritableImage;
    image
        .write()
        .to_file(path)
        .map_err(|e| Error::Invalid(format!("{}: writing EXR: {e}", path.display())))
}

fn smallvec_one(
    c: exr::image::AnyChannel<exr::image::FlatSamples>,
) -> exr::prelude::SmallVec<[exr::image::AnyChannel<exr::image::FlatSamples>; 4]> {
    let mut v = exr::prelude::SmallVec::new();
    v.push(c);
    v
}
