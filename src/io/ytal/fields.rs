//! Reading one y-tal field (one root dataset) with `rust-hdf5`: presence, numbers, enum
//! codes by member name, h5py's bool, points. Every error names the file and the dataset.

use crate::error::{Error, Result};
use glam::{DVec3, Vec3};
use rust_hdf5::{ByteOrder, DatatypeMessage, H5Dataset, H5File};
use std::path::Path;

pub(super) fn field_err(path: &Path, name: &str, e: impl std::fmt::Display) -> Error {
    Error::field(path, name, e.to_string())
}

/// libhdf5 refuses a file shorter than the end-of-file address its superblock records (a
/// truncated copy); rust-hdf5 reads whatever datasets are still whole, so we check it
/// here. The superblock sits at 0 or after a user block of 512 * 2^k bytes.
pub(super) fn check_not_truncated(path: &Path) -> Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    const SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";
    let mut f = crate::io::text::open_regular(path, "an HDF5 capture")?;
    let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut at = 0u64;
    while at + 64 <= len {
        let mut head = [0u8; 64];
        f.seek(SeekFrom::Start(at))
            .and_then(|_| f.read_exact(&mut head))
            .map_err(|e| Error::io(path, e))?;
        if &head[..8] == SIGNATURE {
            // Offsets of sizeof(offsets) and of the base address, per superblock version.
            let (size_at, base_at) = match head[8] {
                0 => (13, 24),
                1 => (13, 28),
                _ => (9, 12),
            };
            let o = usize::from(head[size_at]);
            let addr = |i: usize| -> Option<u64> {
                let b = head.get(base_at + i * o..base_at + (i + 1) * o)?;
                let mut buf = [0u8; 8];
                buf.get_mut(..b.len())?.copy_from_slice(b);
                Some(u64::from_le_bytes(buf)).filter(|_| b.iter().any(|&x| x != 0xff))
            };
            if let (Some(_base), Some(eof)) = (addr(0), addr(2)) {
                // The end-of-file address counts from the file's first byte, user block
                // included (libhdf5 writes 2624 for a 512-byte user block and 2112 bytes
                // of data); adding the base to it refused every file with a user block.
                let need = eof;
                if need > len {
                    return Err(Error::scene(
                        path,
                        format!("truncated HDF5 file: its superblock records {need} bytes, the file has {len}"),
                    ));
                }
            }
            return Ok(());
        }
        at = if at == 0 { 512 } else { at * 2 };
    }
    Ok(())
}

/// The root dataset `name`, or `None` if the file has no such dataset.
pub(super) fn dataset(path: &Path, file: &H5File, name: &str) -> Result<Option<H5Dataset>> {
    if !file.dataset_names().iter().any(|n| n == name) {
        return Ok(None);
    }
    file.dataset(name)
        .map(Some)
        .map_err(|e| field_err(path, name, e))
}

/// The root dataset `name` unless it is absent or has the NULL dataspace (`h5py.Empty`).
fn present(path: &Path, file: &H5File, name: &str) -> Result<Option<H5Dataset>> {
    Ok(dataset(path, file, name)?.filter(|ds| !ds.is_null()))
}

fn is_integer(t: &DatatypeMessage) -> bool {
    matches!(
        t,
        DatatypeMessage::FixedPoint { .. } | DatatypeMessage::BitField { .. }
    )
}

/// Every element as `f64`: floats exactly, integers converted (as h5py would).
fn f64s(ds: &H5Dataset) -> rust_hdf5::Result<Vec<f64>> {
    if is_integer(&ds.datatype()?) {
        Ok(ds
            .read_numeric_as::<i64>()?
            .into_iter()
            .map(|v| v as f64)
            .collect())
    } else {
        ds.read_numeric_as::<f64>()
    }
}

/// Every element as `f32`: a float32 dataset bit for bit, others converted.
pub(super) fn read_f32s(path: &Path, ds: &H5Dataset, name: &str) -> Result<Vec<f32>> {
    let err = |e: rust_hdf5::Hdf5Error| field_err(path, name, e);
    match ds.datatype().map_err(err)? {
        DatatypeMessage::FloatingPoint { size: 4, .. } => ds.read_numeric_as::<f32>().map_err(err),
        _ => Ok(f64s(ds).map_err(err)?.iter().map(|&v| v as f32).collect()),
    }
}

/// The integer held in `bytes`, laid out as the integer type `t`.
fn integer(t: &DatatypeMessage, bytes: &[u8]) -> Option<i64> {
    let (signed, order) = match t {
        DatatypeMessage::FixedPoint {
            signed, byte_order, ..
        } => (*signed, *byte_order),
        DatatypeMessage::BitField { byte_order, .. } => (false, *byte_order),
        _ => return None,
    };
    if bytes.is_empty() || bytes.len() > 8 {
        return None;
    }
    let mut le = bytes.to_vec();
    if order == ByteOrder::BigEndian {
        le.reverse();
    }
    let negative = signed && le.last().is_some_and(|b| b & 0x80 != 0);
    let mut buf = [if negative { 0xff } else { 0 }; 8];
    buf[..le.len()].copy_from_slice(&le);
    Some(i64::from_le_bytes(buf))
}

/// One element per value of an enum dataset: the name of the member it holds (`Err` with
/// the raw value if it holds none of them).
fn enum_names(
    ds: &H5Dataset,
    base: &DatatypeMessage,
    members: &[rust_hdf5::format::messages::datatype::EnumMember],
) -> rust_hdf5::Result<Vec<std::result::Result<String, String>>> {
    let raw = ds.read_raw_bytes()?;
    let size = (base.element_size() as usize).max(1);
    Ok(raw
        .chunks(size)
        .map(|v| {
            members
                .iter()
                .find(|m| m.value == v)
                .map(|m| m.name.clone())
                .ok_or_else(|| integer(base, v).map_or(format!("{v:?}"), |i| i.to_string()))
        })
        .collect())
}

fn one<T: Copy>(path: &Path, name: &str, v: &[T]) -> Result<T> {
    match v {
        [x] => Ok(*x),
        _ => Err(field_err(
            path,
            name,
            format!("holds {} values, expected one", v.len()),
        )),
    }
}

/// The code of the one value of a y-tal enum dataset, whose member names (by code) are
/// `names` (`kind` is the enum's name in y-tal). HDF5 converts enums by member name, and so
/// do we; a plain integer dataset is taken as the code itself.
pub(super) fn read_code(
    path: &Path,
    file: &H5File,
    name: &str,
    kind: &str,
    names: &[&str],
) -> Result<Option<i64>> {
    let Some(ds) = present(path, file, name)? else {
        return Ok(None);
    };
    let err = |e: rust_hdf5::Hdf5Error| field_err(path, name, e);
    let codes: Vec<i64> = match ds.datatype().map_err(err)? {
        t if is_integer(&t) => ds.read_numeric_as::<i64>().map_err(err)?,
        DatatypeMessage::Enum { base, members } => {
            let mut codes = Vec::new();
            for member in enum_names(&ds, &base, &members).map_err(err)? {
                let member = member.map_err(|v| {
                    field_err(path, name, format!("holds {v}, none of its enum's members"))
                })?;
                let code = names.iter().position(|n| *n == member).ok_or_else(|| {
                    field_err(path, name, format!("{member} is not a y-tal {kind}"))
                })?;
                codes.push(code as i64);
            }
            codes
        }
        other => {
            return Err(field_err(
                path,
                name,
                format!("has type {other}, expected y-tal's enum {kind}"),
            ))
        }
    };
    one(path, name, &codes).map(Some)
}

/// h5py's bool (an int8 enum FALSE = 0 / TRUE = 1) or a plain integer (non-zero is true).
pub(super) fn read_bool(path: &Path, file: &H5File, name: &str) -> Result<Option<bool>> {
    let Some(ds) = present(path, file, name)? else {
        return Ok(None);
    };
    let err = |e: rust_hdf5::Hdf5Error| field_err(path, name, e);
    let v: Vec<bool> = match ds.datatype().map_err(err)? {
        t if is_integer(&t) => ds
            .read_numeric_as::<i64>()
            .map_err(err)?
            .iter()
            .map(|&x| x != 0)
            .collect(),
        DatatypeMessage::Enum { base, members } => {
            let mut v = Vec::new();
            for member in enum_names(&ds, &base, &members).map_err(err)? {
                v.push(match member.as_deref() {
                    Ok("TRUE") => true,
                    Ok("FALSE") => false,
                    Ok(other) => {
                        return Err(field_err(
                            path,
                            name,
                            format!("holds {other}, expected h5py's bool (FALSE or TRUE)"),
                        ))
                    }
                    Err(v) => {
                        return Err(field_err(
                            path,
                            name,
                            format!("holds {v}, none of its enum's members"),
                        ))
                    }
                });
            }
            v
        }
        other => {
            return Err(field_err(
                path,
                name,
                format!("has type {other}, expected a bool"),
            ))
        }
    };
    one(path, name, &v).map(Some)
}

/// A dataset's numbers as `f64`; `None` if absent or empty.
fn read_numbers(path: &Path, file: &H5File, name: &str) -> Result<Option<Vec<f64>>> {
    let Some(ds) = present(path, file, name)? else {
        return Ok(None);
    };
    f64s(&ds).map(Some).map_err(|e| field_err(path, name, e))
}

/// A float scalar (or one-element array); `None` if absent or empty.
pub(super) fn read_scalar(path: &Path, file: &H5File, name: &str) -> Result<Option<f64>> {
    let Some(v) = read_numbers(path, file, name)? else {
        return Ok(None);
    };
    match v.as_slice() {
        [x] if x.is_finite() => Ok(Some(*x)),
        [x] => Err(field_err(path, name, format!("must be finite, got {x}"))),
        _ => Err(field_err(
            path,
            name,
            format!("holds {} values, expected one number", v.len()),
        )),
    }
}

/// A point stored as three numbers (`laser_xyz`, `sensor_xyz`); `None` if absent or
/// empty.
pub(super) fn read_point(path: &Path, file: &H5File, name: &str) -> Result<Option<Vec3>> {
    let Some(v) = read_numbers(path, file, name)? else {
        return Ok(None);
    };
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => {
            Ok(Some(Vec3::new(*x as f32, *y as f32, *z as f32)))
        }
        [_, _, _] => Err(field_err(path, name, "holds a non-finite coordinate")),
        _ => Err(field_err(
            path,
            name,
            format!("holds {} values, expected a point (x, y, z)", v.len()),
        )),
    }
}

/// Wall points of a grid dataset: its shape without the trailing 3, and the points in
/// C order.
pub(super) fn read_points(
    path: &Path,
    file: &H5File,
    name: &str,
) -> Result<(Vec<usize>, Vec<DVec3>)> {
    let ds = present(path, file, name)?.ok_or_else(|| {
        field_err(
            path,
            name,
            "missing: a y-tal capture stores its wall points here",
        )
    })?;
    let shape = ds.shape();
    if shape.len() < 2 || shape.last() != Some(&3) {
        return Err(field_err(
            path,
            name,
            format!("has shape {shape:?}, expected (x, y, 3)"),
        ));
    }
    let v = f64s(&ds).map_err(|e| field_err(path, name, e))?;
    if v.len() != shape.iter().product::<usize>() {
        return Err(field_err(
            path,
            name,
            format!("holds {} values for shape {shape:?}", v.len()),
        ));
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(field_err(path, name, "holds a non-finite coordinate"));
    }
    let pts = v.chunks_exact(3).map(DVec3::from_slice).collect();
    Ok((shape[..shape.len() - 1].to_vec(), pts))
}
