//! Writing y-tal's HDF5 captures (`umbra render -o X.hdf5`): the layout and fields of
//! the module above, so y-tal's reconstructions run on Umbra's renders.
//!
//! ## Streaming
//!
//! [`write_ytal_blocks`] takes the transient in blocks of measurement rows (Umbra's
//! flat order: scan points, laser points inside them for exhaustive capture), in any
//! order, so a render split over a cluster is written as its shards arrive and never
//! held in one process (`umbra.distributed.render(out="x.hdf5")`). y-tal puts time
//! first, `(T, Sx, Sy)` / `(T, Lx, Ly, Sx, Sy)`, so a block of rows is a strided piece of
//! `H`; `H` is therefore stored in HDF5 chunks of one row of scan points `(T, Sx, 1)`
//! (one scan point's laser grid `(T, Lx, Ly, 1, 1)` for exhaustive capture), and a
//! block aligned on [`chunk_rows`] fills whole chunks (any other block is still written
//! right, by read-modify-write of the chunks it shares). h5py and libhdf5 read chunked
//! datasets like contiguous ones.

use super::{permute, GRID_FORMAT, H_FORMAT, T_LX_LY_SX_SY, T_SX_SY, X_Y_3};
use crate::error::{Error, Result};
use crate::scene::{CaptureType, ScanGrid, Scene};
use crate::transport::Transient;
use glam::Vec3;
use rust_hdf5::format::messages::datatype::EnumMember;
use rust_hdf5::{DatatypeMessage, H5Dataset, H5File};
use std::path::Path;

/// Grid points as y-tal stores them: `(nx, ny, 3)` indexed `[x, y]`, in C order.
fn grid_points(g: &ScanGrid) -> Vec<f32> {
    let (nx, ny) = (g.nx as usize, g.ny as usize);
    let mut v = Vec::with_capacity(nx * ny * 3);
    for ix in 0..nx {
        for iy in 0..ny {
            v.extend_from_slice(&g.point(iy * nx + ix).to_array());
        }
    }
    v
}

fn normals(n: Vec3, count: usize) -> Vec<f32> {
    (0..count).flat_map(|_| n.to_array()).collect()
}

/// An HDF5 enum over `base` whose member `names[i]` has the value `i` (`width` bytes,
/// little-endian), as `h5py.enum_dtype` writes y-tal's enums and h5py's bool.
fn enum_type(base: DatatypeMessage, width: usize, names: &[&str]) -> DatatypeMessage {
    let members = names
        .iter()
        .enumerate()
        .map(|(i, n)| EnumMember {
            name: (*n).to_string(),
            value: (i as u64).to_le_bytes()[..width].to_vec(),
        })
        .collect();
    DatatypeMessage::enumeration(base, members)
}

/// A short YAML `scene_info` (y-tal parses it with `yaml.load`).
fn scene_info(scene: &Scene) -> String {
    let v = |p: Vec3| format!("[{}, {}, {}]", p.x, p.y, p.z);
    let w = &scene.wall;
    format!(
        "generator: umbra {}\ncapture_type: {}\nrelay_wall:\n  center: {}\n  axis_u: {}\n  axis_v: {}\n  albedo: {}\n",
        env!("CARGO_PKG_VERSION"),
        scene.capture.name(),
        v(w.center),
        v(w.axis_u),
        v(w.axis_v),
        w.albedo
    )
}

/// Writes `t` (rendered for `scene`) as a y-tal capture that `tal.io.read_capture` reads.
pub fn write_ytal(path: &Path, t: &Transient, scene: &Scene) -> Result<()> {
    let expected = scene.output_shape();
    if t.shape != expected || t.data.len() != expected.iter().product::<usize>() {
        return Err(Error::Invalid(format!(
            "{}: the transient has shape {:?} ({} values), but the scene's capture has shape {expected:?}",
            path.display(),
            t.shape,
            t.data.len()
        )));
    }
    write_ytal_blocks(path, scene, |sink| sink(0, &t.data))
}

/// A sink for blocks of a transient: `sink(first_row, values)`, `values` holding whole
/// measurement rows (`bins` values each) from `first_row` on, in Umbra's order.
pub type BlockSink<'a> = dyn FnMut(usize, &[f32]) -> Result<()> + 'a;

/// Writes a y-tal capture of `scene` whose transient `produce` hands to its sink in
/// blocks of rows, in any order (module docs, "Streaming"). Every row must arrive exactly
/// once: an overlapping, out-of-range or ragged block, or a row that never came, is an
/// error naming the rows, and then no file is left. The file appears, complete, at `path`
/// when `produce` returns.
pub fn write_ytal_blocks(
    path: &Path,
    scene: &Scene,
    produce: impl FnOnce(&mut BlockSink<'_>) -> Result<()>,
) -> Result<()> {
    let name = path.display().to_string();
    crate::io::write_via_temp(path, |tmp| {
        let hdf5 = |e: String| Error::Invalid(format!("{name}: writing HDF5: {e}"));
        let layout = Layout::of(scene);
        let file = H5File::create(tmp).map_err(|e| hdf5(e.to_string()))?;
        write_fields(&file, scene).map_err(hdf5)?;
        let h = file
            .new_dataset::<f32>()
            .shape(layout.h_shape())
            .chunk(&layout.h_chunk())
            .create("H")
            .map_err(|e| hdf5(at("H")(e)))?;
        let mut seen = Rows::new(layout.rows());
        produce(&mut |first, values: &[f32]| {
            let rows = layout.block_rows(&name, first, values.len())?;
            seen.mark(&name, first, rows)?;
            layout.write(&h, first, values).map_err(hdf5)
        })?;
        seen.complete(&name)?;
        drop(h);
        file.close().map_err(|e| hdf5(e.to_string()))
    })
}

/// Rows per HDF5 chunk of `H`: blocks starting and ending on multiples of it fill whole
/// chunks (a distributed render cuts its shards there).
pub fn chunk_rows(scene: &Scene) -> usize {
    Layout::of(scene).chunk_rows()
}

/// Umbra's measurement axes (`dims`, slowest first: `sy, sx` or `sy, sx, ly, lx`) and
/// bins, and how they become y-tal's `H` (all axes reversed) and its chunks.
struct Layout {
    dims: Vec<usize>,
    bins: usize,
    /// The fastest measurement axes one chunk spans in full (`sx`; `ly, lx`).
    chunk_axes: usize,
}

/// One piece of a block: rows `first .. first + count * stride(axis)`, where the axes
/// before `axis` are fixed at `at`'s, `axis` runs over `count` values from `at[axis]`,
/// and every axis after it is whole.
struct Box {
    first: usize,
    at: Vec<usize>,
    axis: usize,
    count: usize,
}

impl Layout {
    fn of(scene: &Scene) -> Layout {
        let shape = scene.output_shape();
        let (bins, dims) = shape.split_last().expect("a transient has a time axis");
        Layout {
            dims: dims.to_vec(),
            bins: *bins,
            chunk_axes: if dims.len() == 4 { 2 } else { 1 },
        }
    }

    fn rows(&self) -> usize {
        self.dims.iter().product()
    }

    fn stride(&self, axis: usize) -> usize {
        self.dims[axis + 1..].iter().product()
    }

    fn chunk_rows(&self) -> usize {
        self.stride(self.dims.len() - self.chunk_axes - 1)
    }

    fn h_shape(&self) -> Vec<usize> {
        std::iter::once(self.bins)
            .chain(self.dims.iter().rev().copied())
            .collect()
    }

    fn h_chunk(&self) -> Vec<usize> {
        let m = self.dims.len();
        let chunk = (0..m).map(|k| {
            if k + self.chunk_axes >= m {
                self.dims[k]
            } else {
                1
            }
        });
        let reversed: Vec<usize> = chunk.collect();
        std::iter::once(self.bins)
            .chain(reversed.into_iter().rev())
            .collect()
    }

    /// How many rows `values` (at row `first`) holds, or why it is not a block.
    fn block_rows(&self, name: &str, first: usize, values: usize) -> Result<usize> {
        let rows = values / self.bins.max(1);
        if !values.is_multiple_of(self.bins.max(1)) || first + rows > self.rows() {
            return Err(Error::Invalid(format!(
                "{name}: a block of {values} values at row {first} is not whole rows of {} bins inside the {} measurements",
                self.bins,
                self.rows()
            )));
        }
        Ok(rows)
    }

    /// Rows `a..b` cut into [`Box`]es, greedily: each box is the coarsest one that starts
    /// at `a` and stays inside `a..b` (at most two per axis).
    fn boxes(&self, mut a: usize, b: usize) -> Vec<Box> {
        let mut out = Vec::new();
        while a < b {
            let axis = (0..self.dims.len())
                .find(|&k| a.is_multiple_of(self.stride(k)) && a + self.stride(k) <= b)
                .expect("the fastest axis always fits");
            let s = self.stride(axis);
            let at: Vec<usize> = (0..self.dims.len())
                .map(|k| a / self.stride(k) % self.dims[k])
                .collect();
            let count = (self.dims[axis] - at[axis]).min((b - a) / s);
            out.push(Box {
                first: a,
                at,
                axis,
                count,
            });
            a += count * s;
        }
        out
    }

    /// Writes the rows of `values` (from row `first`) into `h`, box by box: each box's
    /// rows, shaped `(count, dims[axis+1..], T)`, reversed into y-tal's order.
    fn write(
        &self,
        h: &H5Dataset,
        first: usize,
        values: &[f32],
    ) -> std::result::Result<(), String> {
        let rows = values.len() / self.bins.max(1);
        for bx in self.boxes(first, first + rows) {
            let s = self.stride(bx.axis);
            let lo = (bx.first - first) * self.bins;
            let piece = &values[lo..lo + bx.count * s * self.bins];
            let mut shape = vec![bx.count];
            shape.extend_from_slice(&self.dims[bx.axis + 1..]);
            shape.push(self.bins);
            let reverse: Vec<usize> = (0..shape.len()).rev().collect();
            let (data, _) = permute(piece, &shape, &reverse);
            let counts: Vec<usize> = (0..self.dims.len())
                .map(|k| match k.cmp(&bx.axis) {
                    std::cmp::Ordering::Less => 1,
                    std::cmp::Ordering::Equal => bx.count,
                    std::cmp::Ordering::Greater => self.dims[k],
                })
                .collect();
            let starts = std::iter::once(0).chain(bx.at.iter().rev().copied());
            let counts = std::iter::once(self.bins).chain(counts.into_iter().rev());
            h.write_slice(
                &starts.collect::<Vec<_>>(),
                &counts.collect::<Vec<_>>(),
                &data,
            )
            .map_err(at("H"))?;
        }
        Ok(())
    }
}

/// Which measurement rows have been written (one bit each).
struct Rows {
    bits: Vec<u64>,
    n: usize,
}

impl Rows {
    fn new(n: usize) -> Rows {
        Rows {
            bits: vec![0; n.div_ceil(64)],
            n,
        }
    }

    fn get(&self, r: usize) -> bool {
        self.bits[r / 64] >> (r % 64) & 1 == 1
    }

    fn mark(&mut self, name: &str, first: usize, rows: usize) -> Result<()> {
        if let Some(r) = (first..first + rows).find(|&r| self.get(r)) {
            return Err(Error::Invalid(format!(
                "{name}: the block of rows {first}..{} repeats row {r}, written before",
                first + rows
            )));
        }
        for r in first..first + rows {
            self.bits[r / 64] |= 1 << (r % 64);
        }
        Ok(())
    }

    fn complete(&self, name: &str) -> Result<()> {
        match (0..self.n).find(|&r| !self.get(r)) {
            None => Ok(()),
            Some(a) => {
                let b = (a..self.n).find(|&r| self.get(r)).unwrap_or(self.n);
                Err(Error::Invalid(format!(
                    "{name}: rows {a}..{b} of the {} measurements were never written",
                    self.n
                )))
            }
        }
    }
}

/// The f64 nearest the shortest decimal that reads back as `v` (0.01f32 -> 0.01, not
/// 0.0099999998): what the user wrote in the scene.
fn decimal(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(v as f64)
}

/// A failed HDF5 call, named after the dataset it was writing.
fn at(name: &str) -> impl Fn(rust_hdf5::Hdf5Error) -> String + '_ {
    move |e| format!("{name}: {e}")
}

/// Every field but `H` (module docs' table).
fn write_fields(file: &H5File, scene: &Scene) -> std::result::Result<(), String> {
    let exhaustive = scene.capture == CaptureType::Exhaustive;
    let (nx, ny) = (scene.scan.nx as usize, scene.scan.ny as usize);
    let n_w = scene.wall.normal();
    let sensor = grid_points(&scene.scan);
    let (laser, laser_shape) = match scene.capture {
        CaptureType::Single => (scene.laser.target.to_array().to_vec(), [1, 1, 3]),
        CaptureType::Confocal | CaptureType::Exhaustive => (sensor.clone(), [nx, ny, 3]),
    };
    let h_format = if exhaustive { T_LX_LY_SX_SY } else { T_SX_SY };
    let data = |name: &str, shape: &[usize], v: &[f32]| {
        file.new_dataset::<f32>()
            .shape(shape)
            .create(name)
            .and_then(|ds| ds.write_raw(v))
            .map_err(at(name))
    };
    let code = |name: &str, names: &[&str], value: usize| {
        file.new_dataset::<i32>()
            .datatype(enum_type(DatatypeMessage::i32_type(), 4, names))
            .shape([1])
            .create(name)
            .and_then(|ds| ds.write_raw(&[value as i32]))
            .map_err(at(name))
    };
    let scalar = |name: &str, v: f64| {
        file.new_dataset::<f64>()
            .scalar()
            .create(name)
            .and_then(|ds| ds.write_raw(&[v]))
            .map_err(at(name))
    };
    code("H_format", &H_FORMAT, h_format)?;
    data("sensor_xyz", &[3], &scene.detector.origin.to_array())?;
    data("sensor_grid_xyz", &[nx, ny, 3], &sensor)?;
    data("sensor_grid_normals", &[nx, ny, 3], &normals(n_w, nx * ny))?;
    code("sensor_grid_format", &GRID_FORMAT, X_Y_3)?;
    data("laser_xyz", &[3], &scene.laser.origin.to_array())?;
    data("laser_grid_xyz", &laser_shape, &laser)?;
    let laser_normals = normals(n_w, laser_shape[0] * laser_shape[1]);
    data("laser_grid_normals", &laser_shape, &laser_normals)?;
    code("laser_grid_format", &GRID_FORMAT, X_Y_3)?;
    // `tal render` writes None as h5py.Empty(float): the NULL dataspace.
    file.new_dataset::<f64>()
        .null()
        .create("volume_format")
        .map_err(at("volume_format"))?;
    scalar("delta_t", decimal(scene.film.bin_width_opl))?;
    scalar("t_start", decimal(scene.film.start_opl))?;
    // h5py's bool: an int8 enum FALSE = 0, TRUE = 1.
    let flag = "t_accounts_first_and_last_bounces";
    file.new_dataset::<i8>()
        .datatype(enum_type(DatatypeMessage::i8_type(), 1, &["FALSE", "TRUE"]))
        .scalar()
        .create(flag)
        .and_then(|ds| ds.write_raw(&[i8::from(scene.account_first_and_last_bounces)]))
        .map_err(at(flag))?;
    // rust-hdf5 writes a variable-length string dataset with one dimension: (1,) where h5py
    // writes a scalar; y-tal squeezes it to the same string.
    file.write_vlen_strings("scene_info", &[&scene_info(scene)])
        .map(drop)
        .map_err(at("scene_info"))
}
