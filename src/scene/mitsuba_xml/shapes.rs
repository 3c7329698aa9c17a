//! Shapes: hidden `obj`/`rectangle` meshes with their `diffuse` BSDFs, and the relay-wall
//! rectangle with its `nlos_capture_meter`, film and sampler.

use super::params::{Cx, Plugin};
use super::resolve::Resolver;
use super::tree::Node;
use crate::error::Result;
use crate::geometry::mesh::TriMesh;
use crate::scene::{FilmSpec, HiddenObject, KernelSpec, RelayWall, ScanGrid};
use glam::{Affine3A, Mat3, Mat4, Vec3};
use std::collections::HashMap;
use std::path::Path;

pub(super) enum Shape {
    /// A hidden object, and whether it is a Mitsuba `rectangle`.
    Hidden(HiddenObject, bool),
    Wall(Box<WallCfg>),
}

/// The relay wall and what its nlos_capture_meter says.
pub(super) struct WallCfg {
    pub wall: RelayWall,
    pub scan: ScanGrid,
    pub film: FilmSpec,
    pub sensor_origin: Vec3,
    pub sensor_afl: Option<(bool, usize)>,
    /// mitransient's legacy confocal sensor: `original_film_width/height` (the scan
    /// grid, also in `scan`) with a 1x1 film, and the line of the first of them.
    pub legacy_confocal: Option<usize>,
    pub spp: u32,
    pub seed: u64,
    /// (film's exhaustive_scan, its line); (laser_scan_width/height, line).
    pub exhaustive_scan: (bool, usize),
    pub laser_scan: (Option<(i64, i64)>, usize),
}

pub(super) fn shape(
    cx: &mut Cx,
    node: &Node,
    bsdfs: &HashMap<&str, &Node>,
    files: &Resolver,
) -> Result<Shape> {
    let mut p = Plugin::new(node, cx)?;
    let kind = p.kind();
    if kind != "obj" && kind != "rectangle" {
        return Err(cx.err(
            node.line,
            format!("shape type '{kind}' is not supported (obj, rectangle)"),
        ));
    }
    let m = p.transform(cx, "to_world")?.unwrap_or(Mat4::IDENTITY);
    let (albedo, two_sided) = match p.object(cx, &["bsdf", "ref"])? {
        Some(b) => bsdf(cx, b, bsdfs, 0)?,
        None => (0.5, false), // Mitsuba's default: diffuse, reflectance 0.5.
    };
    let det = Mat3::from_mat4(m).determinant();
    let name = |fallback: String| node.attr("id").map(str::to_string).unwrap_or(fallback);
    let (mut mesh, name, reverse) = if kind == "obj" {
        let (file, fline) = p.string(cx, "filename")?.ok_or_else(|| {
            cx.err(
                node.line,
                "<shape type=\"obj\"> needs <string name=\"filename\" value=\"..\"/>",
            )
        })?;
        let face_normals = p.bool(cx, "face_normals")?.unwrap_or(false);
        let flip = p.bool(cx, "flip_normals")?.unwrap_or(false);
        let sensor = p.object(cx, &["sensor"])?;
        if let Some(s) = sensor {
            return Err(cx.err(s.line, "the nlos_capture_meter must sit in a <shape type=\"rectangle\"> (Umbra's relay wall is a rectangle)"));
        }
        p.finish(cx)?;
        let path = files
            .resolve(file)
            .map_err(|m| cx.err(fline, format!("<shape type=\"obj\">: {m}")))?;
        let text = crate::io::read_text(&path, "an OBJ mesh")
            .map_err(|e| cx.err(fline, format!("<shape type=\"obj\">: cannot read {e}")))?;
        let mesh = TriMesh::parse_obj(&text, &path)?;
        let has_vn = text.lines().any(|l| l.trim_start().starts_with("vn "));
        if !face_normals && (has_vn || !is_planar(&mesh)) {
            cx.warn(node.line, format!("Mitsuba shades {file} with {} vertex normals (face_normals = false); Umbra uses the triangles' geometric normals: set <boolean name=\"face_normals\" value=\"true\"/> for the same result in both", if has_vn { "its" } else { "smoothed" }));
        }
        let stem = Path::new(file)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned());
        (mesh, name(stem.unwrap_or_else(|| file.to_string())), flip)
    } else {
        let flip = p.bool(cx, "flip_normals")?.unwrap_or(false);
        if let Some(s) = p.object(cx, &["sensor"])? {
            let u = m.transform_vector3(Vec3::X * 2.0);
            let v = m.transform_vector3(Vec3::Y * 2.0);
            if u.cross(v).length() <= 1e-12 {
                return Err(cx.err(
                    node.line,
                    "the relay wall's to_world flattens it to zero area",
                ));
            }
            p.finish(cx)?;
            let center = m.transform_point3(Vec3::ZERO);
            let mut w = sensor(cx, s)?;
            w.scan.center = center;
            w.scan.axis_u = u;
            w.scan.axis_v = v;
            // Mitsuba's normal is to_world^{-T} · z (negated by flip_normals): flip
            // axis_u when that is opposite to u × v.
            let axis_u = if (det < 0.0) != flip { -u } else { u };
            w.wall = RelayWall {
                center,
                axis_u,
                axis_v: v,
                albedo,
            };
            return Ok(Shape::Wall(Box::new(w)));
        }
        p.finish(cx)?;
        let positions = vec![
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        ];
        let mesh = TriMesh {
            positions,
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            vertex_albedo: None,
        };
        // Keep the front where Mitsuba has it (to_world^{-T} · z): reverse the
        // winding for a mirroring to_world.
        (
            mesh,
            name(format!("rectangle@{}", node.line)),
            (det < 0.0) != flip,
        )
    };
    if reverse {
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
    }
    mesh.transform(&Affine3A::from_mat4(m));
    let dropped = mesh.drop_degenerate();
    if dropped > 0 {
        cx.warn(
            node.line,
            format!("{name}: dropped {dropped} degenerate triangle(s)"),
        );
    }
    if mesh.triangles.is_empty() {
        return Err(cx.err(node.line, format!("{name} has no non-degenerate triangles")));
    }
    Ok(Shape::Hidden(
        HiddenObject {
            name,
            mesh,
            albedo,
            two_sided,
            reflectance: crate::scene::Reflectance::Lambertian,
        },
        kind == "rectangle",
    ))
}

/// Whether all triangles of `mesh` have the same normal (then Mitsuba's smoothed vertex
/// normals equal the face normals).
fn is_planar(mesh: &TriMesh) -> bool {
    let normal = |t: usize| {
        let [a, b, c] = mesh.triangle(t);
        (b - a).cross(c - a).normalize_or_zero()
    };
    let n0 = normal(0);
    (1..mesh.triangles.len()).all(|t| normal(t).dot(n0) > 1.0 - 1e-5)
}

/// `(albedo, two_sided)` of a `<bsdf>` or a `<ref id="..">` to a top-level one.
fn bsdf(cx: &mut Cx, node: &Node, bsdfs: &HashMap<&str, &Node>, depth: u32) -> Result<(f32, bool)> {
    if depth > 4 {
        return Err(cx.err(
            node.line,
            "BSDFs nested or referenced too deeply (a reference cycle?)",
        ));
    }
    if node.tag == "ref" {
        if let Some(a) = node.attrs.iter().find(|a| a.key != "id" && a.key != "name") {
            return Err(cx.err(a.line, format!("<ref>: unknown attribute '{}'", a.key)));
        }
        let id = node
            .attr("id")
            .ok_or_else(|| cx.err(node.line, "<ref> needs an id"))?;
        let target = bsdfs.get(id).ok_or_else(|| {
            cx.err(
                node.line,
                format!("<ref id=\"{id}\">: no top-level <bsdf id=\"{id}\">"),
            )
        })?;
        return bsdf(cx, target, bsdfs, depth + 1);
    }
    let mut p = Plugin::new(node, cx)?;
    let out = match p.kind() {
        "diffuse" => {
            let r = p.mono(cx, "reflectance")?.unwrap_or(0.5);
            if !(0.0..=1.0).contains(&r) {
                return Err(cx.err(p.line_of("reflectance"), format!("diffuse reflectance must be in [0, 1], got {r}")));
            }
            (r, false)
        }
        "twosided" => {
            let inner = p.object(cx, &["bsdf", "ref"])?.ok_or_else(|| cx.err(node.line, "<bsdf type=\"twosided\"> needs one nested diffuse <bsdf> (or <ref>)"))?;
            (bsdf(cx, inner, bsdfs, depth + 1)?.0, true)
        }
        k => return Err(cx.err(node.line, format!("bsdf type '{k}' is not supported: Umbra's surfaces are Lambertian (diffuse, or twosided around a diffuse)"))),
    };
    p.finish(cx)?;
    Ok(out)
}

fn sensor(cx: &mut Cx, node: &Node) -> Result<WallCfg> {
    let mut p = Plugin::new(node, cx)?;
    if p.kind() != "nlos_capture_meter" {
        return Err(cx.err(
            node.line,
            format!(
                "<sensor type=\"{}\">: non-NLOS sensors are not supported; the relay wall carries a <sensor type=\"nlos_capture_meter\">",
                p.kind()
            ),
        ));
    }
    let sensor_origin = p.point(cx, "sensor_origin")?.unwrap_or(Vec3::ZERO);
    let sensor_afl = p
        .bool(cx, "account_first_and_last_bounces")?
        .map(|b| (b, p.line_of("account_first_and_last_bounces")));
    let ow = p.int(cx, "original_film_width")?;
    let oh = p.int(cx, "original_film_height")?;
    let original = match (ow, oh) {
        (None, None) => None,
        (Some((w, lw)), Some((h, lh))) => {
            let pos = |v: i64, l: usize, name: &str| {
                u32::try_from(v).ok().filter(|&v| v > 0).ok_or_else(|| {
                    cx.err(l, format!("{name} must be a positive count, got {v}"))
                })
            };
            Some((
                pos(w, lw, "original_film_width")?,
                pos(h, lh, "original_film_height")?,
                lw.min(lh),
            ))
        }
        (Some((_, l)), None) | (None, Some((_, l))) => {
            return Err(cx.err(l, "give both original_film_width and original_film_height (mitransient's confocal sensor; with only one it ignores it and Mitsuba refuses the other as unreferenced)"))
        }
    };
    let film_node = p.object(cx, &["film"])?.ok_or_else(|| {
        cx.err(
            node.line,
            "the nlos_capture_meter needs a <film type=\"transient_hdr_film\">",
        )
    })?;
    let sampler = p.object(cx, &["sampler"])?;
    p.finish(cx)?;

    let mut f = Plugin::new(film_node, cx)?;
    if f.kind() != "transient_hdr_film" {
        return Err(cx.err(
            film_node.line,
            format!(
                "film type '{}' is not supported: use transient_hdr_film",
                f.kind()
            ),
        ));
    }
    let count = |f: &mut Plugin, cx: &Cx, name: &str, default: Option<i64>| -> Result<u32> {
        let (v, line) = match (f.int(cx, name)?, default) {
            (Some(v), _) => v,
            (None, Some(d)) => (d, film_node.line),
            (None, None) => {
                return Err(cx.err(
                    film_node.line,
                    format!("the transient_hdr_film needs <integer name=\"{name}\">"),
                ))
            }
        };
        u32::try_from(v)
            .ok()
            .filter(|&v| v > 0)
            .ok_or_else(|| cx.err(line, format!("{name} must be a positive count, got {v}")))
    };
    let mut nx = count(&mut f, cx, "width", None)?;
    let mut ny = count(&mut f, cx, "height", None)?;
    if let Some((w, h, _)) = original {
        // mitransient 1.3.1 (nlos_capture_meter): a confocal capture of w x h points
        // taken one point per render through a 1x1 film (y-tal's scan_type: confocal).
        if (nx, ny) != (1, 1) {
            return Err(cx.err(f.line_of("width"), format!("with original_film_width/height the film must be 1 x 1 (mitransient's confocal sensor), got {nx} x {ny}")));
        }
        (nx, ny) = (w, h);
    }
    let temporal_bins = count(&mut f, cx, "temporal_bins", Some(2048))?;
    let bin_width_opl = f.float(cx, "bin_width_opl")?.unwrap_or(0.003);
    if bin_width_opl <= 0.0 {
        return Err(cx.err(
            f.line_of("bin_width_opl"),
            format!("bin_width_opl must be > 0, got {bin_width_opl}"),
        ));
    }
    let start_opl = f.float(cx, "start_opl")?.unwrap_or(0.0);
    let exhaustive_scan = (
        f.bool(cx, "exhaustive_scan")?.unwrap_or(false),
        f.line_of("exhaustive_scan"),
    );
    let lw = f.int(cx, "laser_scan_width")?.map(|v| v.0);
    let lh = f.int(cx, "laser_scan_height")?.map(|v| v.0);
    let laser_scan = (lw.zip(lh), f.line_of("laser_scan_width"));
    if let Some(r) = f.object(cx, &["rfilter"])? {
        let mut rf = Plugin::new(r, cx)?;
        if rf.kind() != "box" {
            return Err(cx.err(
                r.line,
                format!(
                    "rfilter type '{}': mitransient's transient film supports only the box filter",
                    rf.kind()
                ),
            ));
        }
        let _radius = rf.float(cx, "radius")?; // mitransient bins by pixel whatever the radius.
        rf.finish(cx)?;
    }
    f.finish(cx)?;

    let (mut spp, mut seed) = (4u32, 0u64); // Mitsuba's independent sampler defaults.
    if let Some(s) = sampler {
        let mut sp = Plugin::new(s, cx)?;
        if sp.kind() != "independent" {
            return Err(cx.err(
                s.line,
                format!(
                    "sampler type '{}' is not supported: use independent",
                    sp.kind()
                ),
            ));
        }
        if let Some((n, line)) = sp.int(cx, "sample_count")? {
            spp = u32::try_from(n).ok().filter(|&n| n > 0).ok_or_else(|| {
                cx.err(
                    line,
                    format!("sample_count must be a positive count, got {n}"),
                )
            })?;
        }
        if let Some((n, line)) = sp.int(cx, "seed")? {
            seed = u64::try_from(n)
                .map_err(|_| cx.err(line, format!("seed must be >= 0, got {n}")))?;
        }
        sp.finish(cx)?;
    }
    let zero = Vec3::ZERO;
    Ok(WallCfg {
        wall: RelayWall {
            center: zero,
            axis_u: zero,
            axis_v: zero,
            albedo: 0.0,
        },
        scan: ScanGrid {
            nx,
            ny,
            center: zero,
            axis_u: zero,
            axis_v: zero,
        },
        film: FilmSpec {
            temporal_bins,
            bin_width_opl,
            start_opl,
            kernel: KernelSpec::Box,
        },
        sensor_origin,
        sensor_afl,
        legacy_confocal: original.map(|o| o.2),
        spp,
        seed,
        exhaustive_scan,
        laser_scan,
    })
}
