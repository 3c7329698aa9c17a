//! Tangential relaxation with projection back onto the input surface, and the boundary
//! bookkeeping it needs (boundary segments, protected corners).

use super::geom::{add, dot, lerp, norm2, normalized, scale, sub, tri_cross, unit_normal, V3};
use super::halfedge::{HeMesh, NONE};
use super::spatial::Reference;

/// A boundary vertex whose boundary turns by more than this (degrees) is a corner: with
/// `keep_boundary` it is never moved or collapsed.
const CORNER_TURN_DEG: f64 = 35.0;

#[inline]
fn ix(i: u32) -> usize {
    i as usize
}

/// The boundary edges of `m`, each as (origin, target) of its boundary half-edge.
pub(super) fn boundary_segments(m: &HeMesh) -> Vec<[u32; 2]> {
    (0..m.to.len() as u32)
        .filter(|&h| m.to[ix(h)] != NONE && m.face[ix(h)] == NONE)
        .map(|h| [m.from(h), m.to[ix(h)]])
        .collect()
}

/// Marks boundary vertices where the boundary turns by more than [`CORNER_TURN_DEG`].
pub(super) fn mark_corners(m: &mut HeMesh) {
    let cos_limit = CORNER_TURN_DEG.to_radians().cos();
    for v in 0..m.pos.len() as u32 {
        if !m.vertex_alive(ix(v)) || !m.is_boundary_vertex(v) {
            continue;
        }
        let out = m.vhe[ix(v)];
        let inc = m.prev[ix(out)];
        let (u, w) = (m.from(inc), m.to[ix(out)]);
        let d_in = normalized(sub(m.p(v), m.p(u)));
        let d_out = normalized(sub(m.p(w), m.p(v)));
        if let (Some(a), Some(b)) = (d_in, d_out) {
            m.corner[ix(v)] = dot(a, b) < cos_limit;
        }
    }
}

/// One step of tangential relaxation (all vertices at once): interior vertices move by
/// `weight` toward the area-weighted centroid of their neighbours, within their tangent
/// plane; boundary vertices move toward the midpoint of their two boundary neighbours
/// (without `keep_boundary`: only along the line through those neighbours).
/// Every moved vertex is then projected onto the input (onto its boundary when
/// `keep_boundary`, for boundary vertices) and takes the value interpolated there.
/// Corners are left alone when `keep_boundary`. Targets are computed from the old
/// positions; a move that would degenerate or flip a face is skipped.
pub(super) fn relax(m: &mut HeMesh, weight: f64, reference: &Reference, keep_boundary: bool) {
    let nv = m.pos.len();
    let mut normal = vec![[0.0; 3]; nv];
    let mut area = vec![0.0; nv];
    for f in 0..m.fhe.len() as u32 {
        if m.fhe[ix(f)] == NONE {
            continue;
        }
        let vs = m.face_verts(f);
        let n = tri_cross(m.p(vs[0]), m.p(vs[1]), m.p(vs[2]));
        let a = norm2(n).sqrt() / 6.0; // a third of the face's area
        for v in vs {
            normal[ix(v)] = add(normal[ix(v)], n);
            area[ix(v)] += a;
        }
    }
    let mut target: Vec<Option<(V3, f64)>> = vec![None; nv];
    let mut ring = Vec::new();
    for v in 0..nv as u32 {
        if !m.vertex_alive(ix(v)) {
            continue;
        }
        let p = m.p(v);
        let n = normalized(normal[ix(v)]);
        let projected = if m.is_boundary_vertex(v) {
            if keep_boundary && m.corner[ix(v)] {
                continue;
            }
            let out = m.vhe[ix(v)];
            let (u, w) = (m.from(m.prev[ix(out)]), m.to[ix(out)]);
            let target = lerp(m.p(u), m.p(w), 0.5);
            if keep_boundary {
                reference.project_boundary(lerp(p, target, weight))
            } else {
                // Along the boundary's tangent only, so the outline neither shrinks nor
                // loses its corners much.
                let mut d = sub(target, p);
                if let Some(t) = normalized(sub(m.p(w), m.p(u))) {
                    d = scale(t, dot(t, d));
                }
                reference.project_surface(add(p, scale(d, weight)), n)
            }
        } else {
            m.outgoing(v, &mut ring);
            let mut sum = [0.0; 3];
            let mut total = 0.0;
            for &h in &ring {
                let u = m.to[ix(h)];
                sum = add(sum, scale(m.p(u), area[ix(u)]));
                total += area[ix(u)];
            }
            let centroid = if total > 0.0 && total.is_finite() {
                scale(sum, 1.0 / total)
            } else {
                let s = ring.iter().fold([0.0; 3], |s, &h| add(s, m.p(m.to[ix(h)])));
                scale(s, 1.0 / ring.len().max(1) as f64)
            };
            let mut d = sub(centroid, p);
            if let Some(n) = n {
                d = sub(d, scale(n, dot(n, d)));
            }
            reference.project_surface(add(p, scale(d, weight)), n)
        };
        if let Some((q, value)) = projected {
            if q.iter().all(|x| x.is_finite()) {
                target[ix(v)] = Some((q, value));
            }
        }
    }
    // Moves are applied in index order; one that would fold or degenerate a face around
    // the vertex (projection onto a rough input can do that) is dropped.
    for v in 0..nv as u32 {
        if let Some((q, value)) = target[ix(v)] {
            if move_ok(m, v, q, &mut ring) {
                m.pos[ix(v)] = q;
                if !m.val.is_empty() {
                    m.val[ix(v)] = value;
                }
            }
        }
    }
}

/// Whether moving `v` to `q` keeps every face around it non-degenerate and flips none of
/// them (a turn of the normal by 90° or more; slivers may legitimately turn a lot while
/// being repaired).
fn move_ok(m: &HeMesh, v: u32, q: V3, ring: &mut Vec<u32>) -> bool {
    m.outgoing(v, ring);
    let mut reference = [0.0; 3];
    for &h in ring.iter() {
        if m.face[ix(h)] != NONE {
            let (b, c) = (m.to[ix(h)], m.to[ix(m.next[ix(h)])]);
            reference = add(reference, tri_cross(m.p(v), m.p(b), m.p(c)));
        }
    }
    let reference = normalized(reference);
    ring.iter().filter(|&&h| m.face[ix(h)] != NONE).all(|&h| {
        let (b, c) = (m.p(m.to[ix(h)]), m.p(m.to[ix(m.next[ix(h)])]));
        let Some(new) = unit_normal(q, b, c) else {
            return false;
        };
        match unit_normal(m.p(v), b, c).or(reference) {
            Some(old) => dot(old, new) > 0.0,
            None => true,
        }
    })
}
