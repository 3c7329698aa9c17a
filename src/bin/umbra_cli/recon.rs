//! `umbra recon`: a classical reconstruction of a measurement (backprojection, filtered
//! backprojection, the light-cone transform, phasor fields; `umbra::recon::Method`),
//! the surface made of its volume the usual way (per-column argmax depth above a
//! threshold, as a height field), and, with `--truth`, that surface's score against the
//! scene's hidden objects (`umbra::fit::score`): the numbers the baselines study
//! (docs/BASELINES.md) puts next to a fit's.

use std::path::PathBuf;
use std::time::Instant;
use umbra::fit::objective::first_fitted_bin;
use umbra::fit::score::{mesh_depth_map, score_surface, SurfaceScore};
use umbra::geometry::mesh::TriMesh;
use umbra::recon::{
    reconstruct, volume_surface, write_depth_png, write_volume_png, Method, Volume, VoxelGrid,
};
use umbra::scene::Scene;
use umbra::transport::Transient;
use umbra::{Error, Result};

#[derive(clap::Args)]
pub struct ReconArgs {
    /// The measurement: `.npy` (the scene's output layout), y-tal `.hdf5`, or a Stanford
    /// LCT `.mat` (their capture geometry replaces the scene's).
    #[arg(long)]
    pub measured: Option<PathBuf>,
    /// bp, fbp (the depth Laplacian of bp), lct (confocal only) or pf (phasor fields).
    #[arg(long, default_value = "fbp")]
    pub method: String,
    /// Instead of reconstructing: a volume made elsewhere (`.npy`, (ny, nx, nz), depth
    /// fastest, on the grid of --grid and --depths), e.g. y-tal's, to be made a surface
    /// and scored the same way.
    #[arg(long, conflicts_with = "measured")]
    pub volume: Option<PathBuf>,
    /// Instead of reconstructing: a surface mesh (.obj, world space; e.g. a fit's
    /// mesh.obj), its depth map taken on the grid's columns and scored the same way
    /// (with --measured, only the measurement's capture geometry is used).
    #[arg(long, conflicts_with = "volume")]
    pub mesh: Option<PathBuf>,
    /// Voxels NX,NY,NZ over the scan rectangle (default: the scan's resolution, 128).
    #[arg(long, value_parser = parse_dims)]
    pub grid: Option<[usize; 3]>,
    /// Depths Z0,Z1 (m from the wall; default: what the film's time range sees).
    #[arg(long, value_parser = parse_pair)]
    pub depths: Option<[f32; 2]>,
    /// Columns whose peak is below this share of the volume's maximum are empty.
    #[arg(long, default_value_t = 0.3)]
    pub threshold: f32,
    /// Zero the bins before this OPL (m): residual direct light in measured data.
    #[arg(long)]
    pub ignore_before: Option<f32>,
    /// Sum every K consecutive bins first (e.g. 4 or 8 for the 1.2 mm bins of the LCT
    /// captures, where photon noise per bin swamps the reconstruction).
    #[arg(long, default_value_t = 1, value_parser = super::flags::at_least_one)]
    pub time_bin: usize,
    /// Subtract from each histogram the mean of its last tenth of bins: the ambient and
    /// dark-count floor of measured data, which LCT's r³ weight (and any sum over late
    /// bins) turns into a haze growing with depth.
    #[arg(long)]
    pub subtract_floor: bool,
    /// bp/fbp: standard deviation (m of OPL) of a Gaussian blur along time first.
    #[arg(long)]
    pub time_sigma: Option<f32>,
    /// lct: the Wiener filter's signal-to-noise ratio.
    #[arg(long)]
    pub snr: Option<f32>,
    /// pf: the virtual wavelength (m of OPL; default twice the scan spacing).
    #[arg(long)]
    pub wavelength: Option<f32>,
    /// pf: periods within the virtual pulse's ±3σ.
    #[arg(long)]
    pub cycles: Option<f32>,
    /// Score the surface against the scene's hidden objects (summary.toml [score]).
    #[arg(long)]
    pub truth: bool,
    /// Output directory: volume.npy, depth.npy ((ny, nx), m from the wall, NaN where
    /// empty), depth.png, volume.png, surface.obj, summary.toml; with `--mesh`, albedo.npy
    /// ((ny, nx), the mesh's albedo at the first hit, NaN where none) instead of the volume.
    #[arg(short, long, default_value = "out/recon")]
    pub output: PathBuf,
}

fn parse_dims(text: &str) -> std::result::Result<[usize; 3], String> {
    let v: Vec<usize> = text
        .split(',')
        .map(|t| t.trim().parse::<usize>().ok().filter(|&n| n >= 1))
        .collect::<Option<_>>()
        .ok_or_else(|| format!("'{text}' is not NX,NY,NZ (three integers >= 1)"))?;
    <[usize; 3]>::try_from(v).map_err(|_| format!("'{text}' is not NX,NY,NZ"))
}

fn parse_pair(text: &str) -> std::result::Result<[f32; 2], String> {
    let v: Vec<f32> = text
        .split(',')
        .map(|t| t.trim().parse::<f32>().ok().filter(|z| z.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| format!("'{text}' is not Z0,Z1 (two numbers)"))?;
    <[f32; 2]>::try_from(v).map_err(|_| format!("'{text}' is not Z0,Z1"))
}

#[derive(serde::Serialize)]
struct Summary {
    method: String,
    seconds: f64,
    grid_min: [f32; 3],
    grid_max: [f32; 3],
    grid_dims: [usize; 3],
    threshold: f32,
    filled_columns: usize,
    faces: usize,
    score: Option<SurfaceScore>,
}

/// `umbra recon` on `scene` (whose capture the measurement's replaces, if it has one).
pub fn recon(args: ReconArgs, scene: Scene) -> Result<()> {
    let truth = if args.truth {
        Some(umbra::fit::to_mesh(&scene, "truth (--truth)")?)
    } else {
        None
    };
    let (scene, data) = match &args.measured {
        Some(path) => {
            let m = umbra::io::measured::read_measured(path)?;
            let mut s = m.scene_for(&scene)?;
            m.check_against(&s)?;
            let mut data = m.transient.data;
            if args.time_bin > 1 {
                (s.film, data) = umbra::recon::downsample_time(&s.film, &data, args.time_bin)?;
            }
            (s, Some(data))
        }
        None if args.volume.is_some() || args.mesh.is_some() => (scene, None),
        None => {
            return Err(Error::Invalid(
                "umbra recon needs --measured FILE (or --volume VOL.npy, or --mesh MESH.obj)"
                    .into(),
            ))
        }
    };
    let dims = args
        .grid
        .unwrap_or([scene.scan.nx as usize, scene.scan.ny as usize, 128]);
    let grid = match args.depths {
        Some([z0, z1]) => VoxelGrid::over_scan(&scene, z0, z1, dims)?,
        None => VoxelGrid::for_scene(&scene, dims)?,
    };
    let start = Instant::now();
    // The reconstruction's own time (0 for a volume or mesh made elsewhere).
    let mut seconds = 0.0;
    let out = &args.output;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let (name, depth, surface) = if let Some(path) = &args.mesh {
        let mesh = TriMesh::load_obj(path)?;
        let depth = mesh_depth_map(&scene, &umbra::fit::fit_mesh(&mesh), true, &grid);
        // The albedo at each column's hit (a fit's mesh carries it as vertex colours).
        let albedo = depth
            .intensity
            .iter()
            .zip(&depth.depth)
            .map(|(&a, d)| if d.is_finite() { a } else { f32::NAN })
            .collect();
        umbra::io::write_npy(
            &out.join("albedo.npy"),
            &Transient {
                data: albedo,
                shape: vec![dims[1], dims[0]],
            },
        )?;
        ("mesh".to_string(), depth, mesh)
    } else {
        let (name, volume) = match (&args.volume, data) {
            (Some(path), _) => ("volume".to_string(), read_volume(path, &grid)?),
            (None, Some(mut data)) => {
                umbra::fit::objective::check_ignore_before(
                    &scene.film,
                    args.ignore_before,
                    "--ignore-before",
                )?;
                let first = first_fitted_bin(&scene, args.ignore_before);
                umbra::recon::zero_bins_before(&mut data, scene.film.temporal_bins as usize, first);
                if args.subtract_floor {
                    umbra::recon::subtract_floor(&mut data, scene.film.temporal_bins as usize);
                }
                let method = method(&args, &scene)?;
                let volume = reconstruct(&scene, &data, &grid, &method)?;
                seconds = start.elapsed().as_secs_f64();
                (method.name().to_string(), volume)
            }
            (None, None) => unreachable!("checked above"),
        };
        let (depth, surface) = volume_surface(&volume, &scene, args.threshold)?;
        umbra::io::write_npy(
            &out.join("volume.npy"),
            &Transient {
                data: volume.data.clone(),
                shape: vec![dims[1], dims[0], dims[2]],
            },
        )?;
        write_volume_png(&out.join("volume.png"), &volume)?;
        (name, depth, surface)
    };
    umbra::io::write_npy(
        &out.join("depth.npy"),
        &Transient {
            data: depth.depth.clone(),
            shape: vec![dims[1], dims[0]],
        },
    )?;
    write_depth_png(&out.join("depth.png"), &depth)?;
    let mesh = umbra::fit::fit_mesh(&surface);
    let obj = out.join("surface.obj");
    optim::checkpoint::write_atomic(&obj, mesh.to_obj().as_bytes())
        .map_err(|e| Error::io(&obj, e))?;
    let score = match &truth {
        Some(t) => Some(score_surface(&mesh, t, &scene)?),
        None => None,
    };
    let summary = Summary {
        method: name.clone(),
        seconds,
        grid_min: grid.min.to_array(),
        grid_max: grid.max.to_array(),
        grid_dims: dims,
        threshold: args.threshold,
        filled_columns: depth.filled(),
        faces: mesh.faces.len(),
        score: score.clone(),
    };
    let path = out.join("summary.toml");
    let text = toml::to_string(&summary).map_err(|e| Error::Invalid(format!("summary: {e}")))?;
    optim::checkpoint::write_atomic(&path, text.as_bytes()).map_err(|e| Error::io(&path, e))?;
    println!(
        "umbra recon: {name} on {dims:?} voxels in {seconds:.2} s, {} of {} columns filled -> {}",
        depth.filled(),
        dims[0] * dims[1],
        out.display()
    );
    if let Some(s) = score {
        println!(
            "umbra recon: seen Chamfer {:.2} mm, completeness {:.0} % (within {} mm), depth error {:.2} mm mean / {:.2} mm p90 over {:.0} % of the truth's columns",
            s.seen_chamfer_mm,
            100.0 * s.completeness,
            umbra::fit::score::COMPLETE_MM,
            s.depth_error_mean_mm,
            s.depth_error_p90_mm,
            100.0 * s.columns_filled
        );
    }
    Ok(())
}

fn method(args: &ReconArgs, scene: &Scene) -> Result<Method> {
    let mut m = Method::parse(&args.method, scene)?;
    match &mut m {
        Method::Backprojection(o) | Method::Filtered(o) => {
            o.time_sigma_opl = args.time_sigma.unwrap_or(0.0);
        }
        Method::Lct(o) => o.snr = args.snr.unwrap_or(o.snr),
        Method::Phasor(o) => {
            o.wavelength = args.wavelength.unwrap_or(o.wavelength);
            o.cycles = args.cycles.unwrap_or(o.cycles);
        }
    }
    let unused = match m {
        Method::Backprojection(_) | Method::Filtered(_) => [
            ("--snr", args.snr.is_some()),
            ("--wavelength", args.wavelength.is_some()),
            ("--cycles", args.cycles.is_some()),
        ]
        .to_vec(),
        Method::Lct(_) => [
            ("--time-sigma", args.time_sigma.is_some()),
            ("--wavelength", args.wavelength.is_some()),
            ("--cycles", args.cycles.is_some()),
        ]
        .to_vec(),
        Method::Phasor(_) => [
            ("--time-sigma", args.time_sigma.is_some()),
            ("--snr", args.snr.is_some()),
        ]
        .to_vec(),
    };
    if let Some((flag, _)) = unused.iter().find(|(_, given)| *given) {
        return Err(Error::Invalid(format!(
            "{flag} does not apply to --method {}",
            m.name()
        )));
    }
    Ok(m)
}

/// A `(ny, nx, nz)` volume on `grid`, finite.
fn read_volume(path: &std::path::Path, grid: &VoxelGrid) -> Result<Volume> {
    let t = umbra::io::read_npy(path)?;
    let [nx, ny, nz] = grid.dims;
    if t.shape != [ny, nx, nz] {
        return Err(Error::Invalid(format!(
            "{}: volume of shape {:?}, but the grid (--grid) wants ({ny}, {nx}, {nz})",
            path.display(),
            t.shape
        )));
    }
    if let Some(i) = t.data.iter().position(|v| !v.is_finite()) {
        return Err(Error::Invalid(format!(
            "{}: value {i} is not finite",
            path.display()
        )));
    }
    Ok(Volume {
        grid: grid.clone(),
        data: t.data,
    })
}
