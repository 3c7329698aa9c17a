//! y-tal captures written in blocks of rows (`io::ytal::write_ytal_blocks`), as a render
//! split over a cluster arrives: any order, any block size, every capture type, gives the
//! file `write_ytal` writes; a repeated, ragged or missing row is an error naming the
//! rows, and leaves no file behind.

mod common;
use common::capture::small_capture;
use common::tmp_dir;

use rust_hdf5::H5File;
use std::path::Path;
use umbra::io::ytal::{chunk_rows, read_ytal, write_ytal, write_ytal_blocks};
use umbra::scene::{CaptureType, Scene};

const CAPTURES: [CaptureType; 3] = [
    CaptureType::Single,
    CaptureType::Confocal,
    CaptureType::Exhaustive,
];

fn h_of(path: &Path) -> Vec<f32> {
    H5File::open(path)
        .unwrap()
        .dataset("H")
        .unwrap()
        .read_raw()
        .unwrap()
}

/// `(first_row, rows)` blocks covering `n` rows, cut at `cuts`, in the order `order`
/// gives (indices into the blocks).
fn blocks(n: usize, cuts: &[usize], order: impl Fn(usize) -> usize) -> Vec<(usize, usize)> {
    let mut edges = vec![0];
    edges.extend(cuts.iter().copied().filter(|&c| c > 0 && c < n));
    edges.push(n);
    edges.dedup();
    let mut b: Vec<(usize, usize)> = edges.windows(2).map(|w| (w[0], w[1] - w[0])).collect();
    let k = b.len();
    let mut out = Vec::with_capacity(k);
    for i in 0..k {
        out.push(b[order(i) % k]);
    }
    // `order` must be a permutation: every block once.
    b.sort();
    let mut sorted = out.clone();
    sorted.sort();
    assert_eq!(sorted, b, "the test's order is not a permutation");
    out
}

fn stream(
    path: &Path,
    scene: &Scene,
    data: &[f32],
    bins: usize,
    parts: &[(usize, usize)],
) -> umbra::Result<()> {
    write_ytal_blocks(path, scene, |sink| {
        for &(first, rows) in parts {
            sink(first, &data[first * bins..(first + rows) * bins])?;
        }
        Ok(())
    })
}

#[test]
fn blocks_in_any_order_give_the_file_write_ytal_writes() {
    let dir = tmp_dir("ytal-stream-order");
    for capture in CAPTURES {
        let (scene, t) = small_capture(capture);
        let bins = *t.shape.last().unwrap();
        let n = t.data.len() / bins;
        let whole = dir.join(format!("{}-whole.hdf5", capture.name()));
        write_ytal(&whole, &t, &scene).unwrap();
        let reference = h_of(&whole);
        let step = chunk_rows(&scene);
        assert_eq!(
            step,
            if capture == CaptureType::Exhaustive {
                6
            } else {
                3
            },
            "{capture:?}: a chunk is one scan row (one scan point's laser grid)"
        );
        // Chunk-aligned blocks backwards; then ragged cuts (1, 2, 5, 7 rows: partial chunks
        // and blocks across chunk and scan-row edges) in a scrambled order.
        let aligned: Vec<usize> = (step..n).step_by(step).collect();
        let ragged = [1, 3, 5, 10, 17, 24, 25];
        for (tag, cuts, order) in [
            (
                "aligned",
                aligned.as_slice(),
                &(|i: usize| n - 1 - i) as &dyn Fn(usize) -> usize,
            ),
            ("ragged", &ragged[..], &|i: usize| i * 5 + 3),
        ] {
            let k = blocks(n, cuts, |i| i).len();
            let parts = blocks(n, cuts, |i| order(i) % k);
            let path = dir.join(format!("{}-{tag}.hdf5", capture.name()));
            stream(&path, &scene, &t.data, bins, &parts).unwrap();
            let h = h_of(&path);
            assert_eq!(h.len(), reference.len());
            assert!(
                h.iter()
                    .zip(&reference)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{capture:?} {tag}: H differs from write_ytal's"
            );
            let back = read_ytal(&path).unwrap();
            assert_eq!(back.transient.data, t.data, "{capture:?} {tag}");
            assert_eq!(back.capture, Some(capture));
        }
    }
}

/// The error's message, after checking no file (nor temporary) was left in `dir`.
fn refused(dir: &Path, path: &Path, r: umbra::Result<()>) -> String {
    let msg = r.expect_err("the write should fail").to_string();
    assert!(!path.exists(), "a failed write left {}", path.display());
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert!(left.is_empty(), "temporaries left: {left:?}");
    assert!(msg.contains(&path.display().to_string()), "{msg}");
    msg
}

#[test]
fn repeated_ragged_or_missing_rows_are_errors_and_leave_no_file() {
    let dir = tmp_dir("ytal-stream-bad");
    let (scene, t) = small_capture(CaptureType::Exhaustive);
    let bins = *t.shape.last().unwrap();
    let n = t.data.len() / bins; // 36 rows
    let path = dir.join("x.hdf5");

    let msg = refused(
        &dir,
        &path,
        stream(&path, &scene, &t.data, bins, &[(0, 20), (18, 18)]),
    );
    assert!(msg.contains("rows 18..36 repeats row 18"), "{msg}");

    let msg = refused(
        &dir,
        &path,
        stream(&path, &scene, &t.data, bins, &[(0, 10), (20, 16)]),
    );
    assert!(
        msg.contains("rows 10..20 of the 36 measurements were never written"),
        "{msg}"
    );

    let ragged = write_ytal_blocks(&path, &scene, |sink| sink(0, &t.data[..bins * 3 + 2]));
    let msg = refused(&dir, &path, ragged);
    assert!(msg.contains("not whole rows of 7 bins"), "{msg}");

    let past = write_ytal_blocks(&path, &scene, |sink| sink(n - 1, &t.data[..bins * 2]));
    let msg = refused(&dir, &path, past);
    assert!(
        msg.contains(&format!("inside the {n} measurements")),
        "{msg}"
    );

    // The producer's own error (a shard that failed) comes back as it was.
    let failed = write_ytal_blocks(&path, &scene, |sink| {
        sink(0, &t.data[..bins * 6])?;
        Err(umbra::Error::Invalid(format!(
            "{}: shard 3 failed",
            path.display()
        )))
    });
    let msg = refused(&dir, &path, failed);
    assert!(msg.ends_with("shard 3 failed"), "{msg}");
}
