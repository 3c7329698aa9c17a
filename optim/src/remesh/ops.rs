//! The three topological operators of isotropic remeshing (edge split, edge collapse,
//! edge flip) and the passes that apply them over the whole mesh.

use super::geom::{dist2, dot, midpoint, tri_cross, unit_normal, V3};
use super::halfedge::{HeMesh, NONE};
use super::RemeshError;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Faces whose unit normals have a dot product below this meet at a crease: the edge
/// between them is not flipped.
const CREASE_COS: f64 = 0.5;
/// A collapse may turn no surviving face's normal by more than acos(this) (60°).
const COLLAPSE_NORMAL_COS: f64 = 0.5;
/// Passes of the collapse and flip sweeps are repeated until nothing changes, at most this
/// often.
const MAX_PASSES: usize = 32;

#[inline]
fn ix(i: u32) -> usize {
    i as usize
}

/// Splits edge `e` at its midpoint (value: mean of the two ends). Returns the new vertex.
pub(super) fn split_edge(m: &mut HeMesh, e: usize) -> u32 {
    let h = 2 * e as u32;
    let t = h ^ 1;
    let (a, b) = (m.from(h), m.to[ix(h)]);
    let value = 0.5 * (m.value(a) + m.value(b));
    let vm = m.new_vertex(midpoint(m.p(a), m.p(b)), value);
    // h becomes a -> vm, t becomes vm -> a; hb: vm -> b, tb = hb ^ 1: b -> vm.
    let hb = m.new_edge(vm, b);
    let tb = hb ^ 1;
    m.to[ix(h)] = vm;
    let fl = m.face[ix(h)];
    if fl != NONE {
        let (n1, p1) = (m.next[ix(h)], m.prev[ix(h)]);
        let vl = m.to[ix(n1)];
        let s = m.new_edge(vm, vl);
        m.set_face(fl, [h, s, p1]);
        m.new_face([hb, n1, s ^ 1]);
    } else {
        let nx = m.next[ix(h)];
        m.link(h, hb);
        m.link(hb, nx);
    }
    let fr = m.face[ix(t)];
    if fr != NONE {
        let (n2, p2) = (m.next[ix(t)], m.prev[ix(t)]);
        let vr = m.to[ix(n2)];
        let r = m.new_edge(vm, vr);
        m.set_face(fr, [t, n2, r ^ 1]);
        m.new_face([tb, r, p2]);
    } else {
        let pv = m.prev[ix(t)];
        m.link(pv, tb);
        m.link(tb, t);
    }
    if m.vhe[ix(b)] == t {
        m.vhe[ix(b)] = tb;
    }
    m.vhe[ix(vm)] = if fr == NONE { t } else { hb };
    vm
}

/// Splits every edge longer than `sqrt(hi2)` (new edges included) until none is left,
/// longest first: the longest edge of the mesh is the longest edge of both its faces, so
/// this is longest-edge bisection, which never makes the smallest angle much worse (and
/// terminates quickly even on slivers).
pub(super) fn split_long_edges(
    m: &mut HeMesh,
    hi2: f64,
    max_faces: usize,
) -> Result<usize, RemeshError> {
    let len2 = |m: &HeMesh, e: usize| dist2(m.p(m.to[2 * e]), m.p(m.to[2 * e + 1]));
    // Squared lengths are >= 0, so their bit patterns sort like the values; ties go to the
    // lower edge index.
    let mut heap: BinaryHeap<(u64, Reverse<usize>)> = (0..m.n_edges())
        .filter(|&e| m.edge_alive(e) && len2(m, e) > hi2)
        .map(|e| (len2(m, e).to_bits(), Reverse(e)))
        .collect();
    let mut ring = Vec::new();
    let mut count = 0;
    while let Some((bits, Reverse(e))) = heap.pop() {
        if !m.edge_alive(e) || len2(m, e).to_bits() != bits {
            continue;
        }
        let vm = split_edge(m, e);
        count += 1;
        if m.live_faces > max_faces {
            return Err(RemeshError::TooManyFaces { limit: max_faces });
        }
        m.outgoing(vm, &mut ring);
        for &h in &ring {
            let e = (h / 2) as usize;
            let l2 = len2(m, e);
            if l2 > hi2 {
                heap.push((l2.to_bits(), Reverse(e)));
            }
        }
    }
    Ok(count)
}

/// Scratch buffers for the collapse test.
#[derive(Default)]
pub(super) struct Scratch {
    ring_a: Vec<u32>,
    ring_b: Vec<u32>,
    ring: Vec<u32>,
}

/// Whether collapsing half-edge `h` (its origin `a` merges into its target `b`, which moves
/// to `p`) keeps the mesh manifold, creates no edge longer than `sqrt(hi2)` and turns no
/// face normal by more than 60°.
fn collapse_ok(m: &HeMesh, h: u32, p: V3, hi2: f64, keep_boundary: bool, s: &mut Scratch) -> bool {
    let t = h ^ 1;
    let (a, b) = (m.from(h), m.to[ix(h)]);
    if keep_boundary && m.corner[ix(a)] {
        return false;
    }
    let boundary_edge = m.is_boundary_edge(h);
    // A boundary vertex may only slide along a boundary edge (this also forbids pinching
    // the surface by collapsing an interior edge between two boundary vertices).
    if m.is_boundary_vertex(a) && !boundary_edge {
        return false;
    }
    let vl = if m.face[ix(h)] != NONE {
        m.to[ix(m.next[ix(h)])]
    } else {
        NONE
    };
    let vr = if m.face[ix(t)] != NONE {
        m.to[ix(m.next[ix(t)])]
    } else {
        NONE
    };
    // Opposite vertices lose an edge: keep interior valence >= 3, boundary valence >= 2.
    for v in [vl, vr] {
        if v != NONE {
            let min = if m.is_boundary_vertex(v) { 3 } else { 4 };
            if m.valence(v) < min {
                return false;
            }
        }
    }
    m.outgoing(a, &mut s.ring_a);
    m.outgoing(b, &mut s.ring_b);
    // Link condition: the only common neighbours of a and b are the opposite vertices.
    let expected = usize::from(vl != NONE) + usize::from(vr != NONE);
    let mut common = 0;
    for &ha in &s.ring_a {
        let x = m.to[ix(ha)];
        if s.ring_b.iter().any(|&hb| m.to[ix(hb)] == x) {
            if x != vl && x != vr {
                return false;
            }
            common += 1;
        }
    }
    if common != expected {
        return false;
    }
    // No long edges at the merged vertex.
    let long = |ring: &[u32], skip: u32| {
        ring.iter()
            .any(|&g| m.to[ix(g)] != skip && dist2(p, m.p(m.to[ix(g)])) > hi2)
    };
    if long(&s.ring_a, b) || long(&s.ring_b, a) {
        return false;
    }
    // No flipped or degenerate faces.
    let (fl, fr) = (m.face[ix(h)], m.face[ix(t)]);
    let mut reference = [0.0; 3];
    for &g in s.ring_a.iter().chain(&s.ring_b) {
        let f = m.face[ix(g)];
        if f != NONE && f != fl && f != fr {
            let [x, y, z] = m.face_verts(f).map(|v| m.p(v));
            reference = super::geom::add(reference, tri_cross(x, y, z));
        }
    }
    for &g in s.ring_a.iter().chain(&s.ring_b) {
        let f = m.face[ix(g)];
        if f == NONE || f == fl || f == fr {
            continue;
        }
        let vs = m.face_verts(f);
        let old = vs.map(|v| m.p(v));
        let new = vs.map(|v| if v == a || v == b { p } else { m.p(v) });
        let Some(n_new) = unit_normal(new[0], new[1], new[2]) else {
            return false;
        };
        let n_old =
            unit_normal(old[0], old[1], old[2]).or_else(|| super::geom::normalized(reference));
        if let Some(n_old) = n_old {
            if dot(n_old, n_new) < COLLAPSE_NORMAL_COS {
                return false;
            }
        }
    }
    true
}

/// Collapses half-edge `h`: its origin is removed and its target moves to `p` and takes
/// `value`. The caller has checked [`collapse_ok`].
fn collapse(m: &mut HeMesh, h: u32, p: V3, value: f64, s: &mut Scratch) {
    let t = h ^ 1;
    let (a, b) = (m.from(h), m.to[ix(h)]);
    m.outgoing(a, &mut s.ring);
    for &o in &s.ring {
        m.to[ix(o ^ 1)] = b;
    }
    let (fl, fr) = (m.face[ix(h)], m.face[ix(t)]);
    let mut keep = NONE;
    if fl != NONE {
        // Face (a, b, vl) goes; edge a-vl merges into b-vl, whose half-edge n1 takes the
        // place of o (a -> vl) in o's face or boundary loop.
        let (n1, p1) = (m.next[ix(h)], m.prev[ix(h)]);
        let vl = m.to[ix(n1)];
        let o = p1 ^ 1;
        let (po, no, fo) = (m.prev[ix(o)], m.next[ix(o)], m.face[ix(o)]);
        m.link(po, n1);
        m.link(n1, no);
        m.face[ix(n1)] = fo;
        if fo != NONE {
            m.fhe[ix(fo)] = n1;
        }
        if m.vhe[ix(vl)] == p1 {
            m.vhe[ix(vl)] = n1 ^ 1;
        }
        m.kill_edge(p1);
        m.kill_face(fl);
        keep = n1;
    } else {
        let (ph, nh) = (m.prev[ix(h)], m.next[ix(h)]);
        m.link(ph, nh);
    }
    if fr != NONE {
        // Face (b, a, vr) goes; edge a-vr merges into vr-b, whose half-edge p2 takes the
        // place of o (vr -> a) in o's face or boundary loop.
        let (n2, p2) = (m.next[ix(t)], m.prev[ix(t)]);
        let vr = m.to[ix(n2)];
        let o = n2 ^ 1;
        let (po, no, fo) = (m.prev[ix(o)], m.next[ix(o)], m.face[ix(o)]);
        m.link(po, p2);
        m.link(p2, no);
        m.face[ix(p2)] = fo;
        if fo != NONE {
            m.fhe[ix(fo)] = p2;
        }
        if m.vhe[ix(vr)] == o {
            m.vhe[ix(vr)] = p2;
        }
        m.kill_edge(n2);
        m.kill_face(fr);
        keep = p2 ^ 1;
    } else {
        let (pt, nt) = (m.prev[ix(t)], m.next[ix(t)]);
        m.link(pt, nt);
    }
    m.kill_edge(h);
    m.vhe[ix(a)] = NONE;
    m.pos[ix(b)] = p;
    if !m.val.is_empty() {
        m.val[ix(b)] = value;
    }
    let mut ring = std::mem::take(&mut s.ring);
    m.reset_outgoing(b, keep, &mut ring);
    s.ring = ring;
}

/// Collapses edges shorter than `sqrt(lo2)` where [`collapse_ok`] allows it. Interior
/// edges collapse to their midpoint (value: the mean); an edge with a boundary vertex
/// collapses into that vertex, which keeps its position and value.
pub(super) fn collapse_short_edges(
    m: &mut HeMesh,
    lo2: f64,
    hi2: f64,
    keep_boundary: bool,
) -> usize {
    let mut s = Scratch::default();
    let mut count = 0;
    // The first sweep looks at every edge, later ones only at the edges around vertices
    // whose neighbourhood a collapse changed (in edge order).
    let mut candidate = vec![true; m.n_edges()];
    let mut touched = Vec::new();
    for _ in 0..MAX_PASSES {
        touched.clear();
        // Collapses add no edges, so the candidate flags cover every edge index.
        for e in (0..m.n_edges()).filter(|&e| candidate[e]) {
            if !m.edge_alive(e) {
                continue;
            }
            if dist2(m.p(m.to[2 * e]), m.p(m.to[2 * e + 1])) >= lo2 {
                continue;
            }
            for h in [2 * e as u32, 2 * e as u32 + 1] {
                let (a, b) = (m.from(h), m.to[ix(h)]);
                let (p, value) = if m.is_boundary_vertex(a) || m.is_boundary_vertex(b) {
                    (m.p(b), m.value(b))
                } else {
                    (midpoint(m.p(a), m.p(b)), 0.5 * (m.value(a) + m.value(b)))
                };
                if collapse_ok(m, h, p, hi2, keep_boundary, &mut s) {
                    collapse(m, h, p, value, &mut s);
                    count += 1;
                    touched.push(b);
                    break;
                }
            }
        }
        if touched.is_empty() {
            break;
        }
        // Edges of the survivors and of their neighbours.
        candidate.fill(false);
        for &b in &touched {
            if !m.vertex_alive(ix(b)) {
                continue;
            }
            m.outgoing(b, &mut s.ring_a);
            for &h in &s.ring_a {
                m.outgoing(m.to[ix(h)], &mut s.ring_b);
                s.ring_b
                    .iter()
                    .for_each(|&g| candidate[(g / 2) as usize] = true);
            }
        }
    }
    count
}

/// Flips interior edge `h` (a -> b, faces (a, b, c) and (b, a, d)) to d -> c.
fn flip(m: &mut HeMesh, h: u32) {
    let t = h ^ 1;
    let (a, b) = (m.from(h), m.to[ix(h)]);
    let (n1, p1) = (m.next[ix(h)], m.prev[ix(h)]);
    let (n2, p2) = (m.next[ix(t)], m.prev[ix(t)]);
    let (c, d) = (m.to[ix(n1)], m.to[ix(n2)]);
    let (fl, fr) = (m.face[ix(h)], m.face[ix(t)]);
    m.to[ix(h)] = c; // h: d -> c
    m.to[ix(t)] = d; // t: c -> d
    m.set_face(fl, [h, p1, n2]); // (d, c, a)
    m.set_face(fr, [t, p2, n1]); // (c, d, b)
    if m.vhe[ix(a)] == h {
        m.vhe[ix(a)] = n2;
    }
    if m.vhe[ix(b)] == t {
        m.vhe[ix(b)] = n1;
    }
}

/// Flips edges where that brings the valences of the four vertices involved closer to 6
/// (4 on the boundary), in squared deviation; flips across creases, flips that would fold
/// or degenerate a face and flips creating an existing edge are skipped.
pub(super) fn equalize_valences(m: &mut HeMesh) -> usize {
    let nv = m.pos.len();
    let mut valence: Vec<i64> = (0..nv as u32).map(|v| m.valence(v) as i64).collect();
    let target: Vec<i64> = (0..nv as u32)
        .map(|v| {
            if m.vertex_alive(ix(v)) && m.is_boundary_vertex(v) {
                4
            } else {
                6
            }
        })
        .collect();
    let mut ring = Vec::new();
    let mut count = 0;
    for _ in 0..MAX_PASSES {
        let mut pass = 0;
        for e in 0..m.n_edges() {
            let h = 2 * e as u32;
            if !m.edge_alive(e) || m.is_boundary_edge(h) {
                continue;
            }
            let t = h ^ 1;
            let (a, b) = (m.from(h), m.to[ix(h)]);
            let (c, d) = (m.to[ix(m.next[ix(h)])], m.to[ix(m.next[ix(t)])]);
            let vs = [a, b, c, d].map(ix);
            let dev = |delta: [i64; 4]| -> i64 {
                (0..4)
                    .map(|k| (valence[vs[k]] + delta[k] - target[vs[k]]).pow(2))
                    .sum()
            };
            if dev([-1, -1, 1, 1]) >= dev([0; 4]) {
                continue;
            }
            let min_val = |v: u32| if target[ix(v)] == 4 { 3 } else { 4 };
            if c == d || valence[vs[0]] < min_val(a) || valence[vs[1]] < min_val(b) {
                continue;
            }
            m.outgoing(c, &mut ring);
            if ring.iter().any(|&g| m.to[ix(g)] == d) || !flip_geometry_ok(m, [a, b, c, d]) {
                continue;
            }
            flip(m, h);
            valence[vs[0]] -= 1;
            valence[vs[1]] -= 1;
            valence[vs[2]] += 1;
            valence[vs[3]] += 1;
            pass += 1;
        }
        count += pass;
        if pass == 0 {
            break;
        }
    }
    count
}

/// Whether the flip of edge a-b (faces (a, b, c), (b, a, d)) to c-d keeps the surface
/// unfolded: no crease between the old faces, new faces non-degenerate and facing the
/// same way as the old ones.
fn flip_geometry_ok(m: &HeMesh, [a, b, c, d]: [u32; 4]) -> bool {
    let [pa, pb, pc, pd] = [a, b, c, d].map(|v| m.p(v));
    let (Some(m1), Some(m2)) = (unit_normal(pd, pc, pa), unit_normal(pc, pd, pb)) else {
        return false;
    };
    if dot(m1, m2) < CREASE_COS {
        return false;
    }
    match (unit_normal(pa, pb, pc), unit_normal(pb, pa, pd)) {
        (Some(n1), Some(n2)) => {
            let s = super::geom::add(n1, n2);
            dot(n1, n2) >= CREASE_COS && dot(m1, s) > 0.0 && dot(m2, s) > 0.0
        }
        (Some(n), None) | (None, Some(n)) => dot(m1, n) > 0.0 && dot(m2, n) > 0.0,
        (None, None) => true,
    }
}
