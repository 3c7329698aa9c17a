//! Stanford LCT captures (O'Toole, Lindell, Wetzstein, "Confocal non-line-of-sight imaging
//! based on the light-cone transform", Nature 2018): MATLAB v5 `.mat` files with
//!
//! - `rect_data`: photon counts, MATLAB shape `(y, x, t)` stored column-major (y fastest);
//! - `width`: half the side of the square scanned on the wall (m).
//!
//! The capture is confocal over an `N x N` grid on `[-width, width]²`, with 4 ps bins
//! (`c · 4 ps` = 1.199 mm of OPL) and the direct return rectified to bin 0, so a bin's OPL is
//! the round trip wall → hidden scene → wall. The transient comes out in Umbra's
//! (mitransient's) layout `(sy, sx, T)`, row-major, `f32`.

use crate::error::{Error, Result};
use crate::transport::Transient;
use matfile::{MatFile, NumericData};
use std::path::Path;

/// Bin width of the LCT captures: 4 ps of light travel (m of OPL).
pub const LCT_BIN_OPL: f32 = 4e-12 * 299_792_458.0;

/// A read LCT capture.
#[derive(Clone, Debug)]
pub struct LctCapture {
    /// Photon counts, `(sy, sx, T)`.
    pub transient: Transient,
    /// Half the side of the scanned square (m).
    pub width: f32,
    /// OPL per bin (m).
    pub bin_width_opl: f32,
}

fn to_f32(data: &NumericData) -> Vec<f32> {
    match data {
        NumericData::Int8 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::UInt8 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::Int16 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::UInt16 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::Int32 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::UInt32 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::Int64 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::UInt64 { real, .. } => real.iter().map(|&v| v as f32).collect(),
        NumericData::Single { real, .. } => real.clone(),
        NumericData::Double { real, .. } => real.iter().map(|&v| v as f32).collect(),
    }
}

/// Reads an LCT `.mat` capture; a missing variable or a wrong shape is an error naming
/// the file and the variable.
pub fn read_lct(path: &Path) -> Result<LctCapture> {
    let file = super::text::open_regular(path, "a MATLAB .mat capture")?;
    // What matfile skipped or stopped at is named from the file's own layout.
    let why = |name: &str| {
        let bytes = std::fs::read(path).unwrap_or_default();
        super::mat_layout::why_unreadable(&bytes, name)
    };
    let mat = MatFile::parse(std::io::BufReader::new(file)).map_err(|e| {
        let msg = why("rect_data").unwrap_or_else(|| format!("not a MATLAB v5 .mat file: {e}"));
        Error::scene(path, msg)
    })?;
    let find = |name: &str| {
        mat.find_by_name(name).ok_or_else(|| {
            let msg = why(name).unwrap_or_else(|| format!("no variable '{name}'"));
            Error::scene(
                path,
                format!(
                    "{msg} (an LCT capture has rect_data, a numeric y x x x t array, and width)"
                ),
            )
        })
    };
    let rect = find("rect_data")?;
    let &[ny, nx, nt] = rect.size().as_slice() else {
        return Err(Error::scene(
            path,
            format!("rect_data has shape {:?}, expected (y, x, t)", rect.size()),
        ));
    };
    let width = to_f32(find("width")?.data());
    let &[width] = width.as_slice() else {
        return Err(Error::scene(
            path,
            format!(
                "width must be one number (m), got {} values {:?}",
                width.len(),
                &width[..width.len().min(8)]
            ),
        ));
    };
    if !(width.is_finite() && width > 0.0) {
        return Err(Error::scene(
            path,
            format!("width must be a positive number (m), got {width}"),
        ));
    }
    let counts = to_f32(rect.data());
    if let Some(i) = counts.iter().position(|v| !v.is_finite()) {
        return Err(Error::scene(
            path,
            format!("rect_data has a non-finite value at {i}"),
        ));
    }
    // Column-major (y, x, t) -> row-major (y, x, t).
    let mut data = vec![0.0f32; ny * nx * nt];
    for t in 0..nt {
        for x in 0..nx {
            for y in 0..ny {
                data[(y * nx + x) * nt + t] = counts[y + ny * (x + nx * t)];
            }
        }
    }
    Ok(LctCapture {
        transient: Transient {
            data,
            shape: vec![ny, nx, nt],
        },
        width,
        bin_width_opl: LCT_BIN_OPL,
    })
}
