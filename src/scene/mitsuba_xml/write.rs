//! Exporter: an Umbra [`Scene`] as a mitransient 1.3.1 scene (Mitsuba 3 XML plus one
//! world-space OBJ per hidden object), so the same scene renders in both. It writes the
//! subset the importer ([`super::parse`]) reads, and reading the file back gives the
//! same scene (tested), except for what mitransient cannot say:
//!
//! - Sampling techniques: mitransient has no multiple importance sampling. With
//!   hidden-geometry sampling on, the file asks for it alone
//!   (`nlos_hidden_geometry_sampling_do_rroulette = false`; the 50/50 option is biased
//!   in 1.3.1, see the importer); the expected value is the same, the variance is not.
//! - A Gaussian temporal kernel is written as `temporal_filter = gaussian` with
//!   `gaussian_stddev` in metres of OPL: Umbra reads it back, mitransient 1.3.1 reads it
//!   and bins with a box. The export says so in its warnings.
//!
//! Refused, with the field named, before any file is written: a laser given by power
//! (mitransient's projector has an irradiance, DESIGN §2), a laser spot of positive
//! radius or standing on its target, a scan area that is not an axis-aligned
//! rectangle inside the relay wall, a bounce filter mitransient cannot select
//! (it would read it as "off"), Russian roulette from the first bounce, per-vertex
//! albedo, retroreflective objects.
//!
//! A relay wall larger than the scan area (the default scene's): mitransient's
//! `nlos_capture_meter` scans its whole rectangle, so the file's relay wall is the
//! scanned rectangle and the rest of the wall is written as up to four plain
//! rectangles with the same BSDF (same geometry; the importer merges them back).
//!
//! Depths are the inverse of the importer's `mitransient_depth_to_bounces`: with laser
//! sampling `max_depth = max_bounces`, without it `max_bounces + 1`; a bounce filter `f`
//! becomes `filter_bounces = f − 1` (− 1 more without laser sampling).

use crate::error::{Error, Result};
use crate::scene::{CaptureType, KernelSpec, LaserEmission, Reflectance, Scene};
use glam::{DVec3, Vec3};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What [`write`] produced: the XML, the OBJ files, and what mitransient will read
/// differently from Umbra.
pub struct Exported {
    pub xml: PathBuf,
    pub objs: Vec<PathBuf>,
    pub warnings: Vec<String>,
}

fn refuse(xml: &Path, field: &str, msg: impl Into<String>) -> Error {
    Error::Field {
        file: xml.to_path_buf(),
        field: field.to_string(),
        msg: msg.into(),
    }
}

fn v3(v: Vec3) -> String {
    format!("{}, {}, {}", v.x, v.y, v.z)
}

/// Writes `scene` to `xml` (and `<stem>_<object>.obj` next to it).
pub fn write(scene: &Scene, xml: &Path) -> Result<Exported> {
    let ext = xml.extension().and_then(|e| e.to_str());
    if !ext.is_some_and(|e| e.eq_ignore_ascii_case("xml")) {
        return Err(Error::Invalid(format!(
            "{}: a Mitsuba scene is written as .xml (with its meshes as .obj beside it); give a name ending in .xml",
            xml.display()
        )));
    }
    // The output's folder is made, as every other writer makes it.
    if let Some(dir) = xml.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let mut warnings = Vec::new();
    let (wall, scan, laser) = (&scene.wall, &scene.scan, &scene.laser);
    let rest = wall_rest(scene, xml)?;
    if !rest.is_empty() {
        let t = &scene.render.techniques;
        if t.hidden_geometry_sampling
            && !t.hidden_geometry_includes_wall
            && scene.render.max_bounces > 3
        {
            warnings.push("the wall outside the scan area is written as plain rectangles: with hidden-geometry sampling that leaves out the relay wall, mitransient counts multi-bounce paths through them that Umbra leaves out (three-bounce light is the same)".into());
        }
    }
    let LaserEmission::Irradiance {
        irradiance,
        fov_deg,
    } = laser.emission
    else {
        return Err(refuse(
            xml,
            "laser.power",
            "mitransient's projector is given by its irradiance (DESIGN §2): use laser.irradiance",
        ));
    };
    if laser.spot_radius > 0.0 {
        return Err(refuse(
            xml,
            "laser.spot_radius",
            "mitransient's laser spot is a point",
        ));
    }
    // mitransient needs a footprint; the laser-sampled signal does not depend on it.
    let fov_deg = if fov_deg > 0.0 {
        fov_deg
    } else {
        warnings.push(
            "laser.fov unset: the projector is written with fov = 0.2° (its footprint only)".into(),
        );
        0.2
    };
    let r = &scene.render;
    let t = &r.techniques;
    let extra = u32::from(!t.laser_sampling);
    let max_depth = if r.max_bounces == u32::MAX {
        -1
    } else {
        i64::from(r.max_bounces) + i64::from(extra)
    };
    if let Some(f) = r.filter_bounces {
        // mitransient reads filter_bounces = -1 as "off": a filter that selects nothing
        // must not become the whole render.
        if f < 2 + extra || f > r.max_bounces {
            return Err(refuse(xml, "render.filter_bounces", format!("{f} bounces cannot be selected in mitransient with max_bounces = {} and laser sampling {} (2{} to max_bounces)", r.max_bounces, t.laser_sampling, if extra > 0 { " + 1" } else { "" })));
        }
    }
    if r.rr_bounces == 0 {
        return Err(refuse(
            xml,
            "render.rr_bounces",
            "mitransient's rr_depth must be at least 1",
        ));
    }
    let filter = r
        .filter_bounces
        .map_or(-1, |f| i64::from(f) - 1 - i64::from(extra));
    if t.hidden_geometry_sampling && t.bsdf_sampling {
        warnings.push("mitransient has no MIS: the file asks for hidden-geometry sampling alone (same expected value, other variance)".to_string());
    }
    let capture = match scene.capture {
        CaptureType::Single => "single",
        CaptureType::Confocal => "confocal",
        CaptureType::Exhaustive => "exhaustive",
    };
    let filter_xml = match scene.film.kernel {
        KernelSpec::Box => String::from(r#"<string name="temporal_filter" value="box"/>"#),
        KernelSpec::Gaussian { sigma_opl } => {
            warnings.push(format!("temporal_filter = gaussian (σ = {sigma_opl} m of OPL): Umbra reads it, mitransient 1.3.1 bins with a box"));
            format!(
                r#"<string name="temporal_filter" value="gaussian"/>
        <float name="gaussian_stddev" value="{sigma_opl}"/>"#
            )
        }
    };
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<?xml version="1.0" encoding="utf-8"?>
<!-- Written by Umbra (scene::mitsuba_xml::write) for mitransient 1.3.1 (llvm_ad_mono). -->
<scene version="3.9.1">
    <integrator type="transient_nlos_path">
        <string name="capture_type" value="{capture}"/>
        <integer name="max_depth" value="{max_depth}"/>
        <integer name="filter_bounces" value="{filter}"/>
        <integer name="rr_depth" value="{rr}"/>
        <boolean name="discard_direct_paths" value="{discard}"/>
        <boolean name="nlos_laser_sampling" value="{ls}"/>
        <boolean name="nlos_hidden_geometry_sampling" value="{hgs}"/>
        <boolean name="nlos_hidden_geometry_sampling_do_rroulette" value="false"/>
        <boolean name="nlos_hidden_geometry_sampling_includes_relay_wall" value="{hgs_wall}"/>
        <boolean name="account_first_and_last_bounces" value="{afl}"/>
        {filter_xml}
    </integrator>
"#,
        rr = r.rr_bounces.min(i32::MAX as u32),
        discard = r.discard_direct_paths,
        ls = t.laser_sampling,
        hgs = t.hidden_geometry_sampling,
        hgs_wall = t.hidden_geometry_sampling && t.hidden_geometry_includes_wall,
        afl = scene.account_first_and_last_bounces,
    );
    // The projector looks from its origin at its target (single capture) or the wall's
    // centre; `up` is whichever wall axis is less parallel to the beam.
    let target = if scene.capture == CaptureType::Single {
        laser.target
    } else {
        wall.center
    };
    let Some(dir) = (target - laser.origin).try_normalize() else {
        return Err(refuse(
            xml,
            "laser.origin",
            "the laser stands on its target: no beam direction for the projector",
        ));
    };
    let (au, av) = (wall.axis_u.normalize(), wall.axis_v.normalize());
    let up = if dir.dot(av).abs() <= dir.dot(au).abs() {
        av
    } else {
        au
    };
    let _ = write!(
        s,
        r#"    <emitter type="projector" id="laser">
        <rgb name="irradiance" value="{irradiance}, {irradiance}, {irradiance}"/>
        <float name="fov" value="{fov_deg}"/>
        <transform name="to_world">
            <lookat origin="{}" target="{}" up="{}"/>
        </transform>
    </emitter>
"#,
        v3(laser.origin),
        v3(target),
        v3(up)
    );

    let stem = xml
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let dir_out = xml.parent().map(Path::to_path_buf).unwrap_or_default();
    // Everything is checked before any file is written.
    for (i, o) in scene.objects.iter().enumerate() {
        let field = format!("objects[{i}]");
        if o.mesh.vertex_albedo.is_some() {
            return Err(refuse(xml, &field, "per-vertex albedo has no mitransient equivalent here (a uniform diffuse reflectance only)"));
        }
        if o.reflectance != Reflectance::Lambertian {
            return Err(refuse(
                xml,
                &field,
                "mitransient has no retroreflective BSDF",
            ));
        }
    }
    let mut objs = Vec::new();
    for (i, o) in scene.objects.iter().enumerate() {
        let file = format!("{stem}_{i}.obj");
        let path = dir_out.join(&file);
        let mut obj = String::with_capacity(40 * o.mesh.positions.len());
        obj.push_str("# written by Umbra: world coordinates\n");
        for p in &o.mesh.positions {
            let _ = writeln!(obj, "v {} {} {}", p.x, p.y, p.z);
        }
        for t in &o.mesh.triangles {
            let _ = writeln!(obj, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
        }
        optim::checkpoint::write_atomic(&path, obj.as_bytes()).map_err(|e| Error::io(&path, e))?;
        objs.push(path);
        let rho = o.albedo;
        let diffuse = format!(
            r#"<bsdf type="diffuse"><rgb name="reflectance" value="{rho}, {rho}, {rho}"/></bsdf>"#
        );
        let bsdf = if o.two_sided {
            format!(r#"<bsdf type="twosided">{diffuse}</bsdf>"#)
        } else {
            diffuse
        };
        let _ = write!(
            s,
            r#"    <shape type="obj" id="{id}">
        <string name="filename" value="{file}"/>
        <boolean name="face_normals" value="true"/>
        {bsdf}
    </shape>
"#,
            id = xml_id(&o.name, i)
        );
    }

    // The wall: Mitsuba's rectangle [-1, 1]² at z = 0, mapped so that local x spans
    // axis_u, local y axis_v, local z the wall's normal (its front).
    let (hu, hv, n, c) = (
        scan.axis_u * 0.5,
        scan.axis_v * 0.5,
        wall.normal(),
        scan.center,
    );
    for (i, r) in rest.iter().enumerate() {
        let _ = write!(
            s,
            r#"    <shape type="rectangle" id="relay_wall_rest_{i}">
        <transform name="to_world">
            <matrix value="{}"/>
        </transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="{rw}, {rw}, {rw}"/></bsdf>
    </shape>
"#,
            matrix(r[0], r[1], n, r[2]),
            rw = wall.albedo
        );
    }
    let f = &scene.film;
    let _ = write!(
        s,
        r#"    <shape type="rectangle" id="relay_wall">
        <transform name="to_world">
            <matrix value="{}"/>
        </transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="{rw}, {rw}, {rw}"/></bsdf>
        <sensor type="nlos_capture_meter">
            <point name="sensor_origin" x="{}" y="{}" z="{}"/>
            <sampler type="independent">
                <integer name="sample_count" value="{spp}"/>
                <integer name="seed" value="{seed}"/>
            </sampler>
            <film type="transient_hdr_film">
                <integer name="width" value="{nx}"/>
                <integer name="height" value="{ny}"/>
                <integer name="temporal_bins" value="{bins}"/>
                <float name="bin_width_opl" value="{bw}"/>
                <float name="start_opl" value="{start}"/>
                {exhaustive}<rfilter type="box"/>
            </film>
        </sensor>
    </shape>
</scene>
"#,
        matrix(hu, hv, n, c),
        scene.detector.origin.x,
        scene.detector.origin.y,
        scene.detector.origin.z,
        rw = wall.albedo,
        spp = r.spp,
        seed = r.seed,
        nx = scan.nx,
        ny = scan.ny,
        bins = f.temporal_bins,
        bw = f.bin_width_opl,
        start = f.start_opl,
        exhaustive = if scene.capture == CaptureType::Exhaustive {
            format!(
                r#"<boolean name="exhaustive_scan" value="true"/>
                <integer name="laser_scan_width" value="{}"/>
                <integer name="laser_scan_height" value="{}"/>
                "#,
                scan.nx, scan.ny
            )
        } else {
            String::new()
        },
    );
    optim::checkpoint::write_atomic(xml, s.as_bytes()).map_err(|e| Error::io(xml, e))?;
    Ok(Exported {
        xml: xml.to_path_buf(),
        objs,
        warnings,
    })
}

/// Mitsuba's row-major 4x4 `<matrix>` mapping local x, y, z to `hu`, `hv`, `n` and the
/// origin to `c`.
fn matrix(hu: Vec3, hv: Vec3, n: Vec3, c: Vec3) -> String {
    format!(
        "{} {} {} {}  {} {} {} {}  {} {} {} {}  0 0 0 1",
        hu.x, hv.x, n.x, c.x, hu.y, hv.y, n.y, c.y, hu.z, hv.z, n.z, c.z
    )
}

/// The relay wall outside the scan area, as up to four rectangles `(hu, hv, centre)`
/// (half edges and centre, for [`matrix`]): left and right strips of full height, then
/// bottom and top strips as wide as the scan. mitransient's `nlos_capture_meter` scans
/// its whole rectangle, so the file's relay wall is the scanned rectangle and these
/// (same BSDF) are the rest of the wall; Umbra's importer merges them back. Refused,
/// naming the field, when the scan is not an axis-aligned rectangle inside the wall.
fn wall_rest(scene: &Scene, xml: &Path) -> Result<Vec<[Vec3; 3]>> {
    let (wall, scan) = (&scene.wall, &scene.scan);
    let (u, v) = (wall.axis_u.as_dvec3(), wall.axis_v.as_dvec3());
    let (uh, vh) = (u.normalize(), v.normalize());
    let n = wall.normal().as_dvec3();
    let d = (scan.center - wall.center).as_dvec3();
    let (su, sv) = (scan.axis_u.as_dvec3(), scan.axis_v.as_dvec3());
    let scale = u.length() + v.length();
    let tol = 1e-6 * scale;
    let parallel = |a: DVec3, b: DVec3| a.normalize_or_zero().dot(b) >= 1.0 - 1e-9;
    if !(parallel(su, uh) && parallel(sv, vh) && d.dot(n).abs() <= tol) {
        return Err(refuse(xml, "scan", "mitransient's nlos_capture_meter scans its whole relay-wall rectangle: the scan area must lie in the wall's plane with scan.axis_u along wall.axis_u and scan.axis_v along wall.axis_v (then the rest of the wall is written as plain rectangles)"));
    }
    if uh.dot(vh).abs() > 1e-6 {
        return Err(refuse(xml, "wall", "the relay wall's axes are not perpendicular: the rest of the wall around the scan area cannot be written as rectangles"));
    }
    let (hw, hh) = (u.length() / 2.0, v.length() / 2.0);
    let (cs, ct) = (d.dot(uh), d.dot(vh));
    let (a, b) = (su.length() / 2.0, sv.length() / 2.0);
    let (s0, s1, t0, t1) = (cs - a, cs + a, ct - b, ct + b);
    if s0 < -hw - tol || s1 > hw + tol || t0 < -hh - tol || t1 > hh + tol {
        return Err(refuse(xml, "scan", format!("the scan area ({:.4} x {:.4} m at {}) reaches outside the {:.4} x {:.4} m relay wall: make scan.size and scan.center fit in wall.size", 2.0 * a, 2.0 * b, scan.center, 2.0 * hw, 2.0 * hh)));
    }
    let c = wall.center.as_dvec3();
    let mut out = Vec::new();
    let mut strip = |x0: f64, x1: f64, y0: f64, y1: f64| {
        if x1 - x0 > tol && y1 - y0 > tol {
            let centre = c + uh * ((x0 + x1) / 2.0) + vh * ((y0 + y1) / 2.0);
            out.push([
                (uh * ((x1 - x0) / 2.0)).as_vec3(),
                (vh * ((y1 - y0) / 2.0)).as_vec3(),
                centre.as_vec3(),
            ]);
        }
    };
    strip(-hw, s0, -hh, hh);
    strip(s1, hw, -hh, hh);
    strip(s0, s1, -hh, t0);
    strip(s0, s1, t1, hh);
    Ok(out)
}

/// An XML id from an object's name: letters, digits, `_` and `-` kept, the rest `_`,
/// and the index appended so ids stay unique.
fn xml_id(name: &str, i: usize) -> String {
    let clean: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("{clean}_{i}")
}
