//! Shadow-ray culling (`geometry::blockers`): a segment touching hidden triangle `t` is
//! tested only against the triangles that rise above `t`'s plane on the segment's side.
//! Against the full test on the same segments, on a planar letter, a convex sphere, a
//! concave sheet and arc, and the default letter: the two agree except on rays that
//! graze `t`'s plane, where rounding decides either test. And the dead-end continuations
//! that the same heights give (`blockers::Reach`).

mod common;

use common::SceneSpec;
use glam::Vec3;
use std::path::Path;
use umbra::geometry::sampling::cosine_hemisphere;
use umbra::geometry::shapes::{icosphere, wavy_sheet};
use umbra::geometry::SceneGeometry;
use umbra::rng::Sampler;
use umbra::scene::Scene;

fn xml(name: &str) -> Scene {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("python/validation/scenes")
        .join(name);
    Scene::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

fn with_mesh(mesh: umbra::geometry::mesh::TriMesh) -> Scene {
    let mut s = SceneSpec::default().scene();
    s.objects[0].mesh = mesh;
    s
}

/// Exact visibility of the segment `a → b` as intended: `a` on hidden triangle `ta`, `b`
/// on `tb` (or `None`: the wall or free space), both projected onto their planes in `f64`,
/// tested in `f64` against every other triangle and the wall over `[eps, |b − a| − eps]`.
fn reference(geom: &SceneGeometry, (a, ta): (Vec3, u32), (b, tb): (Vec3, Option<u32>)) -> bool {
    let onto = |p: Vec3, t: u32| {
        let tri = &geom.hidden[t as usize];
        let n = tri.n.as_dvec3().normalize();
        let p = p.as_dvec3();
        p - n * n.dot(p - tri.v[0].as_dvec3())
    };
    let a = onto(a, ta);
    let b = tb.map_or(b.as_dvec3(), |t| onto(b, t));
    let dist = (b - a).length();
    let (d, eps) = ((b - a) / dist, geom.eps as f64);
    if dist <= 2.0 * eps {
        return false;
    }
    let hits = |[v0, v1, v2]: [Vec3; 3]| {
        let (v0, e1, e2) = (v0.as_dvec3(), (v1 - v0).as_dvec3(), (v2 - v0).as_dvec3());
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det == 0.0 {
            return false;
        }
        let c = a - v0;
        let u = c.dot(p) / det;
        let q = c.cross(e1);
        let v = d.dot(q) / det;
        let t = e2.dot(q) / det;
        u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t >= eps && t <= dist - eps
    };
    let others = (0..geom.hidden.len() as u32).filter(|&u| u != ta && Some(u) != tb);
    others
        .map(|u| geom.hidden[u as usize].v)
        .chain(geom.wall_tris)
        .any(hits)
}

/// Mismatches against [`reference`] on segments from area-sampled points of the hidden
/// triangles to wall points, to other hidden points and to points in space, either end
/// first, in-plane ones left out: `(segments, full test wrong, culled test wrong, largest |cos θ_t| where the two
/// tests differ)`.
fn compare(geom: &SceneGeometry, wall: &umbra::scene::RelayWall, n: u32) -> (u32, u32, u32, f32) {
    let (mut full_wrong, mut culled_wrong, mut worst) = (0, 0, 0.0f32);
    let point = |s: &mut Sampler| {
        let ts = geom.hidden_area.sample(s.next_2d());
        (geom.hidden[ts.tri as usize].point(ts.bary), ts.tri)
    };
    for i in 0..n {
        let mut s = Sampler::independent(11, 0, i);
        let (a, t) = point(&mut s);
        let (b, tb) = match i % 3 {
            0 => {
                let [u, v] = s.next_2d();
                (
                    wall.center + (u - 0.5) * wall.axis_u + (v - 0.5) * wall.axis_v,
                    None,
                )
            }
            1 => {
                let (b, tb) = point(&mut s);
                (b, Some(tb))
            }
            _ => {
                let ([x, y], [z, _]) = (s.next_2d(), s.next_2d());
                (a + 0.6 * Vec3::new(x - 0.5, y - 0.5, z - 0.5), None)
            }
        };
        // Either end may be the one on t.
        let (p, q) = if i % 2 == 0 { (a, b) } else { (b, a) };
        let (full, culled) = (geom.occluded(p, q), geom.occluded_touching(p, q, t));
        let cos = geom.hidden[t as usize].n.dot((b - a).normalize()).abs();
        if cos < 1e-5 {
            // In t's plane (two points of a planar mesh): visibility there is undefined
            // (0/0 in every triangle test) and such a segment carries no weight.
            continue;
        }
        let truth = reference(geom, (a, t), (b, tb));
        full_wrong += (full != truth) as u32;
        culled_wrong += (culled != truth) as u32;
        if full != culled {
            // Culling only drops hidden triangles: it can clear a segment, never block one.
            assert!(
                full && !culled,
                "culling blocked a segment the full test clears"
            );
            worst = worst.max(cos);
        }
    }
    (n, full_wrong, culled_wrong, worst)
}

#[test]
fn culled_shadow_rays_agree_with_the_full_test() {
    let cases: Vec<(&str, Scene)> = vec![
        ("planar letter T.xml (packets)", xml("T.xml")),
        ("concave arc arc.xml (packets)", xml("arc.xml")),
        (
            "sphere, 320 triangles (BVH)",
            with_mesh(icosphere(Vec3::new(0.0, 0.0, 0.6), 0.2, 2)),
        ),
        (
            "wavy sheet, 50 triangles (packets)",
            with_mesh(wavy_sheet(Vec3::new(0.0, 0.0, 0.6), 0.5, 5, 0.05, 0.3)),
        ),
        (
            "wavy sheet, 200 triangles (BVH)",
            with_mesh(wavy_sheet(Vec3::new(0.0, 0.0, 0.6), 0.5, 10, 0.05, 0.3)),
        ),
        (
            "default planar letter, 72 triangles (BVH)",
            umbra::scene::default::default_scene().unwrap(),
        ),
    ];
    for (name, scene) in cases {
        let geom = SceneGeometry::build(&scene);
        let (n, full_wrong, culled_wrong, worst) = compare(&geom, &scene.wall, 30_000);
        let sides = geom.unblockable_sides();
        eprintln!(
            "{name}: of {n} segments the full test gets {full_wrong} wrong, the culled \
             {culled_wrong} (they differ at |cos| <= {worst:.2e}); {sides} of {} triangle \
             sides cull every hidden triangle",
            2 * geom.hidden.len()
        );
        // Culling is never less exact than the full test, and where they differ the
        // segment grazes the triangle's plane.
        assert!(culled_wrong <= full_wrong, "{name}");
        assert!(culled_wrong <= n / 1000, "{name}: {culled_wrong} of {n}");
        assert!(worst < 0.05, "{name}: a segment at |cos| {worst} differs");
    }
}

/// What the sets are on shapes whose answer is known: a planar mesh culls every hidden
/// triangle from both sides, a convex one from the outside, a concave one not everywhere.
#[test]
fn blocker_sets_of_known_shapes() {
    let t = SceneGeometry::build(&xml("T.xml"));
    assert_eq!(t.unblockable_sides(), 2 * t.hidden.len());
    let sphere = SceneGeometry::build(&with_mesh(icosphere(Vec3::new(0.0, 0.0, 0.6), 0.2, 2)));
    assert_eq!(sphere.unblockable_sides(), sphere.hidden.len());
    let sheet = SceneGeometry::build(&with_mesh(wavy_sheet(
        Vec3::new(0.0, 0.0, 0.6),
        0.5,
        5,
        0.05,
        0.3,
    )));
    let culled = sheet.unblockable_sides();
    assert!(culled > 0 && culled < 2 * sheet.hidden.len(), "{culled}");
}

/// Dead-end and wall-only continuations (`geometry::blockers::Reach`,
/// `path_step::Onward`): from a side of a hidden triangle that reaches no other hidden
/// triangle, every point that hidden-geometry sampling can draw lies behind the
/// triangle's plane or within `τ = eps/4` of it (heights in `f64` of points projected
/// onto their planes), so the dropped continuations have `cos θ_x ≤ 0` up to the
/// rounding of a planar mesh; and a BSDF ray's full trace meets what the wall-only
/// trace meets, or hidden geometry within `τ` of the plane. And
/// the counts on known shapes: a planar letter reaches nothing from either side, a convex
/// sphere nothing from the outside, a concave arc and sheet something.
#[test]
fn dead_end_sides_reach_nothing() {
    let cases: Vec<(&str, Scene, Option<usize>)> = vec![
        ("planar letter T.xml", xml("T.xml"), Some(8)),
        ("concave arc arc.xml", xml("arc.xml"), None),
        (
            "sphere, 320 triangles",
            with_mesh(icosphere(Vec3::new(0.0, 0.0, 0.6), 0.2, 2)),
            Some(320),
        ),
        (
            "wavy sheet, 50 triangles",
            with_mesh(wavy_sheet(Vec3::new(0.0, 0.0, 0.6), 0.5, 5, 0.05, 0.3)),
            None,
        ),
        (
            "default planar letter, 72 triangles",
            umbra::scene::default::default_scene().unwrap(),
            Some(144),
        ),
    ];
    for (name, scene, expected) in cases {
        let geom = SceneGeometry::build(&scene);
        let onto = |p: Vec3, t: u32| {
            let tri = &geom.hidden[t as usize];
            let n = tri.n.as_dvec3().normalize();
            let p = p.as_dvec3();
            p - n * n.dot(p - tri.v[0].as_dvec3())
        };
        let tau = 0.25 * geom.eps as f64 + 1e-12;
        let (mut dead, mut grazing) = (0, 0);
        let mut s = Sampler::independent(5, 1, 0);
        for t in 0..geom.hidden.len() as u32 {
            let tri = geom.hidden[t as usize];
            for n_side in [tri.n, -tri.n] {
                if geom.reach_from(t, n_side).hidden {
                    continue;
                }
                dead += 1;
                for _ in 0..64 {
                    let x = onto(tri.point(s.next_2d()), t);
                    let ts = geom.hidden_area.sample(s.next_2d());
                    let y = onto(geom.hidden[ts.tri as usize].point(ts.bary), ts.tri);
                    let h = n_side.as_dvec3().normalize().dot(y - x);
                    assert!(
                        h <= tau,
                        "{name}: triangle {t} reaches {} at height {h}",
                        ts.tri
                    );
                    // BSDF sampling from this side (`path_step::Onward::WallOnly`) traces
                    // the wall alone: the full trace meets the same wall point, or
                    // nothing, or hidden geometry within τ of the plane (rounding).
                    let x = tri.point(s.next_2d());
                    let dir = cosine_hemisphere(n_side, s.next_2d()).dir;
                    let wall = geom.intersect_wall(x, dir).map(|h| h.t.to_bits());
                    match geom.intersect(x, dir) {
                        Some(hit) if hit.flat != u32::MAX => {
                            let h = n_side
                                .as_dvec3()
                                .normalize()
                                .dot(hit.p.as_dvec3() - onto(x, t));
                            assert!(h <= tau, "{name}: a ray from {t} meets {} at {h}", hit.flat);
                            grazing += 1;
                        }
                        full => assert_eq!(full.map(|h| h.t.to_bits()), wall, "{name}: {t}"),
                    }
                }
            }
        }
        eprintln!(
            "{name}: {dead} of {} triangle sides are dead ends ({grazing} rays grazing)",
            2 * geom.hidden.len()
        );
        match expected {
            Some(e) => assert_eq!(dead, e, "{name}"),
            None => assert!(dead < 2 * geom.hidden.len(), "{name}: {dead}"),
        }
    }
    // The wall is in front of the letter: reachable from its front side, not its back.
    let t = SceneGeometry::build(&xml("T.xml"));
    let n = t.hidden[0].n;
    let toward_wall = if n.dot(t.wall_normal) < 0.0 { n } else { -n };
    assert!(t.reach_from(0, toward_wall).wall && !t.reach_from(0, -toward_wall).wall);
}

/// A point of hidden triangle `t`, uniform by area (the square folded onto the triangle).
fn point_on(geom: &SceneGeometry, t: u32, s: &mut Sampler) -> Vec3 {
    let [mut b1, mut b2] = s.next_2d();
    if b1 + b2 > 1.0 {
        (b1, b2) = (1.0 - b1, 1.0 - b2);
    }
    geom.hidden[t as usize].point([b1, b2])
}

/// Next-event culling toward a point spot (`geometry::point_shadow`): from a triangle that
/// `clear_toward(l)` clears, no segment to `l` is blocked by a hidden triangle, by the
/// `f64` reference and by the full test, for spots across the wall; and on shapes that do
/// shadow themselves some triangles stay uncleared.
#[test]
fn triangles_cleared_toward_a_spot_see_it() {
    let cases: Vec<(&str, Scene)> = vec![
        ("concave arc arc.xml", xml("arc.xml")),
        (
            "wavy sheet, 50 triangles",
            with_mesh(wavy_sheet(Vec3::new(0.0, 0.0, 0.6), 0.5, 5, 0.05, 0.3)),
        ),
    ];
    for (name, scene) in cases {
        let geom = SceneGeometry::build(&scene);
        let w = &scene.wall;
        let (mut cleared, mut kept, mut segments) = (0u32, 0u32, 0u32);
        for (i, (fu, fv)) in [
            (0.5, 0.5),
            (0.1, 0.1),
            (0.9, 0.2),
            (0.3, 0.85),
            (0.95, 0.95),
        ]
        .into_iter()
        .enumerate()
        {
            let l = w.center + (fu - 0.5) * w.axis_u + (fv - 0.5) * w.axis_v;
            let clear = geom.clear_toward(l);
            for t in 0..geom.hidden.len() as u32 {
                if (clear >> t) & 1 == 0 {
                    kept += 1;
                    continue;
                }
                cleared += 1;
                let mut s = Sampler::independent(17, i as u64, t);
                for _ in 0..400 {
                    let a = point_on(&geom, t, &mut s);
                    segments += 1;
                    assert!(
                        !reference(&geom, (a, t), (l, None)),
                        "{name}: tri {t}, spot {l}"
                    );
                    assert!(
                        !geom.occluded_touching(a, l, t),
                        "{name}: tri {t}, spot {l}"
                    );
                }
            }
        }
        eprintln!(
            "{name}: {cleared} triangle-spot pairs cleared, {kept} kept, {segments} segments"
        );
        assert!(cleared > 0, "{name}: nothing cleared");
        if name.starts_with("wavy") {
            assert!(
                kept > 0,
                "{name}: a self-shadowing sheet cleared everywhere"
            );
        }
    }
}

/// `MeasurementCtx::occluded_touching`, which tests only the wall where a segment from a
/// cleared triangle ends at the spot centre or the sensor point, answers as the full
/// `SceneGeometry::occluded_touching` on the same segments, in either order, for single
/// and confocal captures of the arc; and it does clear most of them.
#[test]
fn culled_segments_to_the_measurement_points_answer_as_the_full_test() {
    use umbra::film::Film;
    use umbra::scene::CaptureType;
    use umbra::transport::MeasurementCtx;
    for capture in [CaptureType::Single, CaptureType::Confocal] {
        let mut scene = xml("arc.xml");
        scene.capture = capture;
        let geom = SceneGeometry::build(&scene);
        let film = Film::new(&scene.film);
        let (mut segments, mut cleared) = (0u32, 0u32);
        for m in (0..scene.num_measurements()).step_by(37) {
            let ctx = MeasurementCtx::new(&scene, &geom, &film, m);
            for end in [ctx.x_l, ctx.x_s] {
                let clear = geom.clear_toward(end);
                for t in 0..geom.hidden.len() as u32 {
                    cleared += ((clear >> t) & 1) as u32;
                    let mut s = Sampler::independent(5, m as u64, t);
                    for _ in 0..50 {
                        let a = point_on(&geom, t, &mut s);
                        segments += 1;
                        assert_eq!(
                            ctx.occluded_touching(a, end, t),
                            geom.occluded_touching(a, end, t),
                            "{capture:?}: measurement {m}, tri {t}, end {end}"
                        );
                        assert_eq!(
                            ctx.occluded_touching(end, a, t),
                            geom.occluded_touching(end, a, t),
                            "{capture:?}: measurement {m}, tri {t}, end {end} (reversed)"
                        );
                    }
                }
            }
        }
        let pairs = segments / 50;
        eprintln!("{capture:?}: {cleared} of {pairs} triangle-point pairs cleared");
        assert!(2 * cleared > pairs, "{capture:?}: few pairs cleared");
    }
}
