//! Importer for the subset of Mitsuba 3 XML that mitransient 1.3.1 users write for NLOS
//! scenes (y-tal writes it too): a `transient_nlos_path` integrator, one `projector`
//! laser, a `rectangle` relay wall carrying a `nlos_capture_meter` with a
//! `transient_hdr_film`, and hidden `obj`/`rectangle` shapes with `diffuse` (optionally
//! `twosided`) BSDFs. Anything outside the subset is an error naming the element and the
//! line; nothing is silently ignored (what Umbra reads but does not model becomes a
//! warning in [`Scene::warnings`]).
//!
//! Mapping decisions (mitransient 1.3.1 semantics, read from its source):
//! - The wall's rectangle is Mitsuba's `[-1, 1]^2` at `z = 0` mapped by `to_world`. Film
//!   pixel `(ix, iy)` scans the rectangle's local point
//!   `(2 (ix + ½)/width - 1, 2 (iy + ½)/height - 1, 0)`, so the scan's `axis_u` is
//!   `to_world · (2, 0, 0)` (film x) and `axis_v` is `to_world · (0, 2, 0)` (film y); scan
//!   index `iy * width + ix` is mitransient's `(sy, sx)` order. The wall's front is
//!   Mitsuba's normal `to_world^{-T} · (0, 0, 1)`; for a mirroring `to_world` the wall's
//!   `axis_u` is negated so that `axis_u × axis_v` still points to the front (the scan
//!   keeps the film's orientation).
//! - The laser stands at the projector's `to_world` translation and aims along its local
//!   +z (as mitransient, which traces that ray); in single capture its target is where
//!   that ray meets the wall (an error if it points away or misses the wall). y-tal
//!   writes a translation-only `to_world` and aims the laser at run time: such a laser
//!   is aimed at the wall's centre, with a warning, unless `-D laser_lookat_x/y` aim it
//!   as y-tal does (module `ytal`: y-tal's run-time aim, its 1x1 confocal film with
//!   `original_film_width/height`, and `-D scan_type=exhaustive`).
//! - Relative file names: Mitsuba's search order (module `resolve`): `<path>` folders,
//!   the XML's folder, the working directory. A `-D name=value` the file never uses
//!   (`$name`) is an error, as in Mitsuba, except y-tal's run-time names.
//! - Rectangles that extend the relay wall in its plane with its BSDF are merged into it
//!   (module `wall_merge`): how a wall larger than its scan area is written.
//! - A top-level non-NLOS `<sensor>` (a `perspective` camera) is named as unsupported.
//! - Depths: see [`mitransient_depth_to_bounces`].

mod params;
mod resolve;
mod shapes;
mod tree;
mod wall_merge;
pub mod write;
mod ytal;

#[cfg(test)]
mod tests;

use super::{
    CaptureType, Detector, FilmSpec, KernelSpec, Laser, LaserEmission, Model, RelayWall,
    RenderSettings, Scene, Techniques,
};
use crate::error::{Error, Result};
use glam::{Mat3, Mat4, Vec3};
use params::{Cx, Plugin};
use resolve::Resolver;
use shapes::{shape, Shape, WallCfg};
use std::collections::HashMap;
use std::path::Path;
use tree::Node;

/// Mitsuba's `projector` field of view when none is given (degrees; what Mitsuba 3.9
/// reports for a default projector).
const DEFAULT_PROJECTOR_FOV: f32 = 34.0221;

/// Reads a Mitsuba XML scene; relative OBJ filenames resolve as Mitsuba resolves them
/// (`<path>` folders, the XML's folder, then the current working directory).
pub fn load(path: &Path) -> Result<Scene> {
    load_with_defines(path, &[])
}

/// [`load`] with `$name` values set from outside (Mitsuba's `-D name=value`; y-tal's
/// run-time `laser_lookat_x/y` and `scan_type=exhaustive`, see the `ytal` module).
pub fn load_with_defines(path: &Path, defines: &[(String, String)]) -> Result<Scene> {
    let cwd = std::env::current_dir().ok();
    load_in(path, defines, cwd.as_deref())
}

/// [`load_with_defines`] as if run in the folder `cwd` (`None`: search only next to
/// the XML).
pub fn load_in(path: &Path, defines: &[(String, String)], cwd: Option<&Path>) -> Result<Scene> {
    let text = crate::io::read_text(path, "a Mitsuba XML scene")?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    build(&text, path, Resolver::new(&base, cwd), defines)
}

/// Parses Mitsuba XML text. `origin` names it in messages; relative OBJ filenames are
/// looked for in `base_dir`, then in the current working directory.
pub fn parse(text: &str, origin: &Path, base_dir: &Path) -> Result<Scene> {
    parse_with_defines(text, origin, base_dir, &[])
}

/// [`parse`] with `$name` values set from outside (Mitsuba's `-D name=value`).
pub fn parse_with_defines(
    text: &str,
    origin: &Path,
    base_dir: &Path,
    defines: &[(String, String)],
) -> Result<Scene> {
    let cwd = std::env::current_dir().ok();
    build(
        text,
        origin,
        Resolver::new(base_dir, cwd.as_deref()),
        defines,
    )
}

fn build(
    text: &str,
    origin: &Path,
    mut files: Resolver,
    defines: &[(String, String)],
) -> Result<Scene> {
    let parsed = tree::parse(text, origin, defines)?;
    let run = ytal::split_defines(&parsed, origin, defines)?;
    let root = &parsed.root;
    let mut cx = Cx {
        origin,
        warnings: Vec::new(),
    };
    if root.tag != "scene" {
        return Err(cx.err(
            root.line,
            format!("the root element must be <scene>, not <{}>", root.tag),
        ));
    }
    if root.attr("version").is_none() {
        return Err(cx.err(root.line, "<scene> needs a version attribute"));
    }
    if let Some(a) = root.attrs.iter().find(|a| a.key != "version") {
        return Err(cx.err(a.line, format!("<scene>: unknown attribute '{}'", a.key)));
    }
    not_an_nlos_scene(&cx, root)?;

    let mut bsdfs: HashMap<&str, &Node> = HashMap::new();
    let (mut integrator, mut emitter, mut shapes) = (None, None, Vec::new());
    for c in &root.children {
        match c.tag.as_str() {
            "default" => {}
            "integrator" | "emitter" => {
                let slot = if c.tag == "integrator" { &mut integrator } else { &mut emitter };
                if slot.is_some() {
                    return Err(cx.err(c.line, format!("a second <{}>: an NLOS scene has exactly one", c.tag)));
                }
                *slot = Some(c);
            }
            "shape" => shapes.push(c),
            "bsdf" => {
                let id = c.attr("id").ok_or_else(|| {
                    cx.err(c.line, "a top-level <bsdf> needs an id (shapes refer to it with <ref id=\"..\"/>)")
                })?;
                if bsdfs.insert(id, c).is_some() {
                    return Err(cx.err(c.line, format!("a second <bsdf id=\"{id}\">")));
                }
            }
            "sensor" => {
                return Err(cx.err(c.line, "the <sensor type=\"nlos_capture_meter\"> must be nested in the relay wall's <shape type=\"rectangle\">"))
            }
            "path" => {
                if let Some(a) = c.attrs.iter().find(|a| a.key != "value") {
                    return Err(cx.err(a.line, format!("<path>: unknown attribute '{}'", a.key)));
                }
                if let Some(k) = c.children.first() {
                    return Err(cx.err(k.line, "<path> has a child element"));
                }
                let dir = c.attr("value").ok_or_else(|| cx.err(c.line, "<path> needs a value attribute (a folder to search for files)"))?;
                files.prepend(dir, c.line).map_err(|m| cx.err(c.line, m))?;
            }
            t => {
                return Err(cx.err(c.line, format!("unknown element <{t}> (Umbra reads <default>, <path>, <integrator>, <emitter>, <shape> and <bsdf> at the top level)")))
            }
        }
    }
    let integ_node = integrator.ok_or_else(|| {
        Error::scene(
            origin,
            "no <integrator type=\"transient_nlos_path\">: Umbra imports mitransient NLOS scenes",
        )
    })?;
    let integ = integrator_cfg(&mut cx, integ_node)?;

    let mut wall: Option<(WallCfg, usize)> = None;
    let mut objects = Vec::new();
    for s in shapes {
        let shape = shape(&mut cx, s, &bsdfs, &files)?;
        match shape {
            Shape::Hidden(o, is_rect) => objects.push((o, is_rect)),
            Shape::Wall(w) => {
                if let Some((_, first)) = wall {
                    return Err(cx.err(s.line, format!("a second relay wall (the first, with its nlos_capture_meter, is at line {first})")));
                }
                wall = Some((*w, s.line));
            }
        }
    }
    let (mut w, _) = wall.ok_or_else(|| {
        Error::scene(origin, "no relay wall: a <shape type=\"rectangle\"> must carry the <sensor type=\"nlos_capture_meter\">")
    })?;
    let (merged_wall, objects) = wall_merge::merge(&mut cx, w.wall.clone(), objects);
    w.wall = merged_wall;
    let em_node = emitter
        .ok_or_else(|| Error::scene(origin, "no laser: add an <emitter type=\"projector\">"))?;
    // y-tal's legacy confocal sensor and its run-time requests (see `ytal`).
    let (capture, aimed, scan) = ytal::resolve(
        &cx,
        run,
        integ.capture,
        integ.capture_line,
        w.legacy_confocal,
        &w.scan,
    )?;
    let laser = projector(&mut cx, em_node, &w.wall, capture, aimed)?;

    if let Some((afl, line)) = w.sensor_afl {
        if afl != integ.afl {
            cx.warn(line, format!("account_first_and_last_bounces = {afl} on the nlos_capture_meter is deprecated and ignored by mitransient 1.3.1; the integrator's value ({}) is used", integ.afl));
        }
    }
    let (exhaustive_scan, laser_scan) = (w.exhaustive_scan, w.laser_scan);
    if (integ.capture == CaptureType::Exhaustive) != exhaustive_scan.0 {
        return Err(cx.err(exhaustive_scan.1, "mitransient needs <boolean name=\"exhaustive_scan\" value=\"true\"/> on the film exactly when capture_type is exhaustive"));
    }
    if exhaustive_scan.0 && laser_scan.0 != Some((w.scan.nx as i64, w.scan.ny as i64)) {
        return Err(cx.err(laser_scan.1, "exhaustive capture: laser_scan_width and laser_scan_height must equal the film's width and height (mitransient's force_equal_illumination_scanning)"));
    }

    let scene = Scene {
        detector: Detector {
            origin: w.sensor_origin,
        },
        wall: w.wall,
        laser,
        scan,
        capture,
        film: FilmSpec {
            kernel: integ.kernel,
            ..w.film
        },
        account_first_and_last_bounces: integ.afl,
        objects,
        render: RenderSettings {
            spp: w.spp,
            seed: w.seed,
            ..integ.render
        },
        warnings: cx.warnings,
    };
    scene.validate(origin)?;
    Ok(scene)
}

/// A top-level `<sensor>` that is not an NLOS capture meter (a `perspective` camera,
/// say: y-tal's steady and ground-truth scenes) makes this a scene Umbra cannot render;
/// say so before anything else is judged.
fn not_an_nlos_scene(cx: &Cx, root: &Node) -> Result<()> {
    for c in root.children.iter().filter(|c| c.tag == "sensor") {
        let kind = c.attr("type").unwrap_or("");
        if kind != "nlos_capture_meter" {
            return Err(cx.err(c.line, format!("<sensor type=\"{kind}\">: non-NLOS sensors are not supported. Umbra renders NLOS captures only: a <sensor type=\"nlos_capture_meter\"> nested in the relay wall's <shape type=\"rectangle\"> (y-tal's nlos_scene.xml; its steady_scene.xml and ground_truth_scene.xml are for Mitsuba's own cameras)")));
        }
    }
    Ok(())
}

/// What the integrator element says, converted to Umbra's terms.
struct IntegratorCfg {
    capture: CaptureType,
    /// Line of capture_type (the integrator's if absent).
    capture_line: usize,
    afl: bool,
    kernel: KernelSpec,
    /// spp and seed come from the sensor's sampler.
    render: RenderSettings,
}

fn integrator_cfg(cx: &mut Cx, node: &Node) -> Result<IntegratorCfg> {
    let mut p = Plugin::new(node, cx)?;
    match p.kind() {
        "transient_nlos_path" => {}
        "transient_path" => return Err(cx.err(node.line, "<integrator type=\"transient_path\"> is mitransient's line-of-sight integrator: NLOS scenes use transient_nlos_path")),
        k => return Err(cx.err(node.line, format!("integrator type '{k}' is not supported: Umbra imports <integrator type=\"transient_nlos_path\">"))),
    }
    let _block_size = p.int(cx, "block_size")?; // Parallelism only.
    let capture_line = p.line_of("capture_type");
    let capture = match p.take(cx, "capture_type", &["string", "integer"])? {
        None => CaptureType::Single,
        Some(n) => {
            let v = n.attr("value").unwrap_or("").trim();
            let c = match v.to_ascii_lowercase().as_str() {
                "1" if n.tag == "integer" => Some(CaptureType::Single),
                "2" if n.tag == "integer" => Some(CaptureType::Confocal),
                "3" if n.tag == "integer" => Some(CaptureType::Exhaustive),
                s if n.tag == "string" => CaptureType::parse(s),
                _ => None,
            };
            c.ok_or_else(|| cx.err(n.line, format!("capture_type '{v}' is not one of single, confocal, exhaustive (or 1, 2, 3)")))?
        }
    };
    let laser_sampling = p.bool(cx, "nlos_laser_sampling")?.unwrap_or(false);
    let hg = p
        .bool(cx, "nlos_hidden_geometry_sampling")?
        .unwrap_or(false);
    // mitransient ignores these two unless hidden-geometry sampling is on.
    // (Both read even then, so that they are not reported as unknown.)
    let hg_rr = p
        .bool(cx, "nlos_hidden_geometry_sampling_do_rroulette")?
        .unwrap_or(false)
        && hg;
    let hg_wall = p
        .bool(cx, "nlos_hidden_geometry_sampling_includes_relay_wall")?
        .unwrap_or(false)
        && hg;
    if hg_rr {
        cx.warn(p.line_of("nlos_hidden_geometry_sampling_do_rroulette"), "nlos_hidden_geometry_sampling_do_rroulette = true: mitransient 1.3.1 then picks hidden-geometry or BSDF sampling 50/50 without MIS and doubles its result (a mitransient bug); Umbra combines the two without that bias");
    }
    if !laser_sampling {
        cx.warn(p.line_of("nlos_laser_sampling"), "nlos_laser_sampling = false: mitransient then lights the projector's whole footprint (fov), whose scale is not comparable with laser sampling on; Umbra imports a point laser spot, which its path model reaches only by laser sampling");
    }
    let discard = p.bool(cx, "discard_direct_paths")?.unwrap_or(false);
    if discard && !laser_sampling {
        cx.warn(p.line_of("discard_direct_paths"), "discard_direct_paths with nlos_laser_sampling = false: mitransient then also drops three-bounce paths (it tests depth > 2 at the light connection); Umbra drops only laser-spot-to-sensor-point paths");
    }
    let afl = p
        .bool(cx, "account_first_and_last_bounces")?
        .unwrap_or(false);
    if p.bool(cx, "force_equal_illumination_scanning")? == Some(false) {
        return Err(cx.err(p.line_of("force_equal_illumination_scanning"), "force_equal_illumination_scanning = false is not supported: Umbra's exhaustive capture lights the scan grid's points"));
    }
    let _scan_fov = p.float(cx, "illumination_scan_fov")?; // Only used when the above is false.
    if p.bool(cx, "camera_unwarp")? == Some(true) {
        return Err(cx.err(p.line_of("camera_unwarp"), "camera_unwarp = true: mitransient refuses it with transient_nlos_path (use account_first_and_last_bounces)"));
    }
    // No effect on a transient_nlos_path render with a projector.
    let _ = (
        p.bool(cx, "hide_emitters")?,
        p.bool(cx, "discard_direct_light")?,
    );
    if let Some((d, line)) = p.int(cx, "nlos_hidden_geometry_sampling_max_depth")? {
        if d != -1 {
            return Err(cx.err(line, format!("nlos_hidden_geometry_sampling_max_depth = {d}: Umbra has no depth limit for hidden-geometry sampling (only -1 is supported)")));
        }
    }

    let (max_depth, md_line) = p.int(cx, "max_depth")?.unwrap_or((6, node.line));
    let (rr_depth, rr_line) = p.int(cx, "rr_depth")?.unwrap_or((5, node.line));
    let fb = p.int(cx, "filter_bounces")?;
    let fd = p.int(cx, "filter_depth")?;
    let filter_depth = match (fb, fd) {
        (Some((b, l)), Some((d, _))) if b != -1 && d != -1 => {
            return Err(cx.err(
                l,
                "give only one of filter_bounces and filter_depth (mitransient refuses both)",
            ))
        }
        (Some((b, l)), _) if b != -1 => Some((b.saturating_add(1), l)), // mitransient: filter_depth = filter_bounces + 1
        (_, Some((d, l))) if d != -1 => Some((d, l)),
        _ => None,
    };
    if max_depth < -1 || max_depth == 0 {
        return Err(cx.err(
            md_line,
            format!("max_depth must be -1 (unbounded) or positive, got {max_depth}"),
        ));
    }
    if let Some((d, l)) = filter_depth {
        if d < 1 {
            return Err(cx.err(l, format!("filter_bounces/filter_depth must be -1 (off) or select a path length, got depth {d}")));
        }
    }
    if rr_depth <= 0 {
        return Err(cx.err(
            rr_line,
            format!("rr_depth must be positive, got {rr_depth}"),
        ));
    }
    let (max_bounces, filter_bounces) =
        mitransient_depth_to_bounces(max_depth, filter_depth.map(|f| f.0), laser_sampling);
    if max_bounces < 3 {
        let need = if laser_sampling { 3 } else { 4 };
        return Err(cx.err(md_line, format!("max_depth = {max_depth} renders no NLOS (three-bounce) light: with nlos_laser_sampling = {laser_sampling} it must be at least {need}, or -1")));
    }
    if let (Some(f), Some((_, l))) = (filter_bounces, filter_depth) {
        if f < 2 || f > max_bounces {
            return Err(cx.err(l, format!("with nlos_laser_sampling = {laser_sampling} this bounce filter selects paths of {f} surface vertices (laser spot to sensor point), but paths have from 2 to {max_bounces} here (max_depth = {max_depth}): the render would be zero")));
        }
    }

    let filter = p.string(cx, "temporal_filter")?;
    let stddev = p.float(cx, "gaussian_stddev")?;
    let kernel = match filter.map(|f| (f.0.trim(), f.1)) {
        None | Some(("", _)) | Some(("box", _)) => {
            if stddev.is_some() {
                cx.warn(
                    p.line_of("gaussian_stddev"),
                    "gaussian_stddev is ignored: the temporal filter is a box",
                );
            }
            KernelSpec::Box
        }
        Some(("gaussian", line)) => {
            let sigma = stddev.ok_or_else(|| cx.err(line, "temporal_filter = gaussian needs <float name=\"gaussian_stddev\"> (metres of OPL)"))?;
            if sigma <= 0.0 {
                return Err(cx.err(
                    p.line_of("gaussian_stddev"),
                    format!("gaussian_stddev must be > 0, got {sigma}"),
                ));
            }
            cx.warn(line, "temporal_filter = gaussian: Umbra smooths time with a Gaussian of gaussian_stddev metres of OPL; mitransient 1.3.1 reads this setting but always bins with a box");
            KernelSpec::Gaussian { sigma_opl: sigma }
        }
        Some((f, line)) => {
            return Err(cx.err(
                line,
                format!("temporal_filter '{f}' is not one of box, gaussian"),
            ))
        }
    };
    p.finish(cx)?;
    Ok(IntegratorCfg {
        capture,
        capture_line,
        afl,
        kernel,
        render: RenderSettings {
            spp: 1,
            max_bounces,
            filter_bounces,
            discard_direct_paths: discard,
            // Russian roulette does not change the expectation; mitransient starts it
            // at vertex depth rr_depth, Umbra after rr_bounces bounces.
            rr_bounces: u32::try_from(rr_depth).unwrap_or(u32::MAX),
            // Umbra's own roulette before that (mitransient has none; CLI
            // `--rr-early-survival`).
            rr_early_survival: crate::scene::EarlySurvival::Auto,
            seed: 0,
            model: Model::Path,
            techniques: Techniques {
                laser_sampling,
                hidden_geometry_sampling: hg,
                hidden_geometry_includes_wall: hg_wall,
                // mitransient samples directions by hidden-geometry sampling alone, or
                // (with do_rroulette) picks it or BSDF sampling with probability ½.
                bsdf_sampling: !hg || hg_rr,
            },
            visibility: super::Visibility::Centroid,
            subdivision: super::DEFAULT_SUBDIVISION,
            // mitransient traces the laser beam and the detector's view.
            visible_legs: true,
            boundary_terms: true,
            max_error: super::DEFAULT_MAX_ERROR,
        },
    })
}

/// Converts mitransient's depths to Umbra's bounce counts (the number of surface
/// vertices from the laser spot to the sensor point, both included: 3 = laser spot,
/// one hidden point, sensor point). Returns `(max_bounces, filter_bounces)`.
///
/// In mitransient 1.3.1's `transient_nlos_path` the sensor point is vertex depth 0, and
/// light is gathered at vertex depth `d` only while `d + 1 < max_depth`, by next-event
/// estimation evaluated "at depth" `e`; `filter_bounces = n` means `filter_depth = n + 1`
/// and keeps contributions with `e == filter_depth`.
/// - Laser sampling on: vertex `d` connects to the laser spot, and the estimator runs at
///   `e = d + 2`; the path has `d + 2` bounces. So `max_bounces = max_depth` and the
///   filter is `filter_depth` (= `filter_bounces + 1`: `filter_bounces = 2` selects
///   three bounces, DESIGN §7).
/// - Laser sampling off: vertex `d` is itself the laser spot, lit by next-event
///   estimation to the projector with `e = d`; the path has `d + 1` bounces. So
///   `max_bounces = max_depth - 1` and the filter is `filter_depth + 1`.
///
/// `max_depth = -1` is unbounded (`u32::MAX`). Inputs are validated by the caller
/// (`max_depth` is -1 or positive, `filter_depth >= 1`).
fn mitransient_depth_to_bounces(
    max_depth: i64,
    filter_depth: Option<i64>,
    laser_sampling: bool,
) -> (u32, Option<u32>) {
    let extra: i64 = if laser_sampling { 0 } else { 1 };
    let to_u32 = |v: i64| u32::try_from(v.max(0)).unwrap_or(u32::MAX);
    let max_bounces = if max_depth < 0 {
        u32::MAX
    } else {
        to_u32(max_depth - extra)
    };
    (
        max_bounces,
        filter_depth.map(|d| to_u32(d.saturating_add(extra))),
    )
}

/// The laser of `<emitter type="projector">`; `aimed`: the target y-tal aims it at (its
/// `to_world` direction is then replaced, as y-tal's `focus_emitter_at_relay_wall_pixel`
/// does).
fn projector(
    cx: &mut Cx,
    node: &Node,
    wall: &RelayWall,
    capture: CaptureType,
    aimed: Option<Vec3>,
) -> Result<Laser> {
    let mut p = Plugin::new(node, cx)?;
    if p.kind() != "projector" {
        return Err(cx.err(
            node.line,
            format!(
                "emitter type '{}' is not supported: the laser is an <emitter type=\"projector\">",
                p.kind()
            ),
        ));
    }
    let irradiance =
        p.mono(cx, "irradiance")?.unwrap_or(1.0) * p.float(cx, "scale")?.unwrap_or(1.0);
    if irradiance < 0.0 {
        return Err(cx.err(
            p.line_of("irradiance"),
            format!("the projector's irradiance must be >= 0, got {irradiance}"),
        ));
    }
    let fov_deg = p.float(cx, "fov")?.unwrap_or(DEFAULT_PROJECTOR_FOV);
    let m = p.transform(cx, "to_world")?.unwrap_or(Mat4::IDENTITY);
    let xf_line = p.line_of("to_world");
    p.finish(cx)?;

    let origin = m.transform_point3(Vec3::ZERO);
    let dir = m.transform_vector3(Vec3::Z);
    if wall.height_above(origin) <= 0.0 {
        return Err(cx.err(xf_line, format!("the laser at {origin} is behind (or on) the relay wall: it must be on the side the wall faces")));
    }
    let n = wall.normal();
    let toward = dir.dot(n);
    let hit = (toward < 0.0).then(|| origin + dir * ((wall.center - origin).dot(n) / toward));
    let on_wall = |h: Vec3| {
        // Solve h - centre = s U + t V in the wall's plane.
        let (u, v, d) = (wall.axis_u, wall.axis_v, h - wall.center);
        let (uu, uv, vv) = (u.dot(u), u.dot(v), v.dot(v));
        let det = uu * vv - uv * uv;
        let s = (vv * d.dot(u) - uv * d.dot(v)) / det;
        let t = (uu * d.dot(v) - uv * d.dot(u)) / det;
        s.abs() <= 0.5 + 1e-4 && t.abs() <= 0.5 + 1e-4
    };
    let translation_only = Mat3::from_mat4(m).abs_diff_eq(Mat3::IDENTITY, 1e-6);
    let target = if let Some(t) = aimed {
        t
    } else {
        match hit {
            _ if capture != CaptureType::Single => hit.filter(|&h| on_wall(h)).unwrap_or(wall.center),
            Some(h) if on_wall(h) => h,
            Some(h) if !translation_only => {
                return Err(cx.err(xf_line, format!("the laser's beam (its local +z) meets the relay wall's plane at {h}, outside the wall")))
            }
            None if !translation_only => {
                return Err(cx.err(xf_line, format!("the laser points away from the relay wall (its local +z is {dir})")))
            }
            _ => {
                cx.warn(xf_line, format!("the projector's to_world is a translation only (y-tal aims the laser at run time): aiming it at the relay wall's centre {}, y-tal's default; -D laser_lookat_x=.. -D laser_lookat_y=.. aim it at a film pixel as y-tal does", wall.center));
                wall.center
            }
        }
    };
    Ok(Laser {
        origin,
        target,
        emission: LaserEmission::Irradiance {
            irradiance,
            fov_deg,
        },
        spot_radius: 0.0,
    })
}
