//! Self-intersection check of a triangle mesh: pairs of triangles that share no
//! vertex yet come closer than a clearance. Written here because the crates that
//! do it (parry's, for one) test exact contact only; a mesh whose separate
//! sheets nearly touch is misjudged by the floating-point tests of tools it is
//! exported to (Open3D, slicers), so the clearance is what we check.
//!
//! Triangles that share a vertex are skipped, as Open3D's
//! `get_self_intersecting_triangles` does.

use super::TriangleMesh;
use crate::numeric::floor_i64;
use std::collections::HashMap;

type P = [f64; 3];

fn sub(a: P, b: P) -> P {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: P, b: P) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: P, b: P) -> P {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn along(a: P, d: P, t: f64) -> P {
    [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]]
}
fn distance(a: P, b: P) -> f64 {
    let d = sub(a, b);
    dot(d, d).sqrt()
}

/// Distance from `p` to triangle `t`, mm (Ericson, Real-Time Collision
/// Detection, 5.1.5).
fn point_triangle(p: P, [a, b, c]: [P; 3]) -> f64 {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return distance(p, a);
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return distance(p, b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return distance(p, along(a, ab, d1 / (d1 - d3)));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return distance(p, c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return distance(p, along(a, ac, d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return distance(p, along(b, sub(c, b), w));
    }
    let denom = 1.0 / (va + vb + vc);
    let q = along(along(a, ab, vb * denom), ac, vc * denom);
    distance(p, q)
}

/// Distance between segments `p1 q1` and `p2 q2`, mm (Ericson 5.1.9).
fn segment_segment(p1: P, q1: P, p2: P, q2: P) -> f64 {
    let (d1, d2, r) = (sub(q1, p1), sub(q2, p2), sub(p1, p2));
    let (a, e, f) = (dot(d1, d1), dot(d2, d2), dot(d2, r));
    let (s, t) = if a <= f64::MIN_POSITIVE && e <= f64::MIN_POSITIVE {
        (0.0, 0.0)
    } else if a <= f64::MIN_POSITIVE {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = dot(d1, r);
        if e <= f64::MIN_POSITIVE {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = dot(d1, d2);
            let denom = a * e - b * b;
            let mut s = if denom > 0.0 {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    distance(along(p1, d1, s), along(p2, d2, t))
}

/// Whether segment `p q` passes through the inside of triangle `t` (strictly:
/// touching cases are left to the distance tests).
fn segment_crosses(p: P, q: P, [a, b, c]: [P; 3]) -> bool {
    let n = cross(sub(b, a), sub(c, a));
    let (sp, sq) = (dot(n, sub(p, a)), dot(n, sub(q, a)));
    if sp * sq >= 0.0 {
        return false;
    }
    let pq = sub(q, p);
    let side = |u: P, v: P| dot(pq, cross(sub(u, p), sub(v, p)));
    let (s1, s2, s3) = (side(a, b), side(b, c), side(c, a));
    (s1 > 0.0 && s2 > 0.0 && s3 > 0.0) || (s1 < 0.0 && s2 < 0.0 && s3 < 0.0)
}

fn segment_triangle(p: P, q: P, t: [P; 3]) -> f64 {
    if segment_crosses(p, q, t) {
        return 0.0;
    }
    let mut d = point_triangle(p, t).min(point_triangle(q, t));
    for e in 0..3 {
        d = d.min(segment_segment(p, q, t[e], t[(e + 1) % 3]));
    }
    d
}

/// Distance between two triangles, mm: zero when they intersect. Disjoint
/// triangles' closest points include one on an edge, so the six edge-triangle
/// distances cover it.
pub fn triangle_distance(s: [P; 3], t: [P; 3]) -> f64 {
    let mut d = f64::INFINITY;
    for e in 0..3 {
        d = d.min(segment_triangle(s[e], s[(e + 1) % 3], t));
        d = d.min(segment_triangle(t[e], t[(e + 1) % 3], s));
    }
    d
}

/// Pairs of triangles (indices, lower first) that share no vertex and are
/// closer than `clearance_mm`, in ascending order.
pub fn self_intersections(mesh: &TriangleMesh, clearance_mm: f64) -> Vec<[u32; 2]> {
    let corners = |t: &[u32; 3]| t.map(|i| mesh.vertices[i as usize].map(f64::from));
    let boxes: Vec<(P, P)> = mesh
        .triangles
        .iter()
        .map(|t| {
            let c = corners(t);
            let lo = std::array::from_fn(|x| c[0][x].min(c[1][x]).min(c[2][x]) - clearance_mm);
            let hi = std::array::from_fn(|x| c[0][x].max(c[1][x]).max(c[2][x]) + clearance_mm);
            (lo, hi)
        })
        .collect();
    // Cells as large as the largest box, so a box spans at most 2 per axis.
    let cell = boxes
        .iter()
        .flat_map(|(lo, hi)| (0..3).map(move |x| hi[x] - lo[x]))
        .fold(f64::MIN_POSITIVE, f64::max);
    let cell_of = |v: f64| floor_i64(v / cell);
    let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (i, (lo, hi)) in boxes.iter().enumerate() {
        for cx in cell_of(lo[0])..=cell_of(hi[0]) {
            for cy in cell_of(lo[1])..=cell_of(hi[1]) {
                for cz in cell_of(lo[2])..=cell_of(hi[2]) {
                    cells.entry([cx, cy, cz]).or_default().push(i as u32);
                }
            }
        }
    }
    let overlap = |a: usize, b: usize| {
        let ((la, ha), (lb, hb)) = (boxes[a], boxes[b]);
        (0..3).all(|x| la[x] <= hb[x] && lb[x] <= ha[x])
    };
    let mut pairs = Vec::new();
    for members in cells.values() {
        for (n, &a) in members.iter().enumerate() {
            for &b in &members[n + 1..] {
                let (ta, tb) = (mesh.triangles[a as usize], mesh.triangles[b as usize]);
                if ta.iter().any(|v| tb.contains(v)) || !overlap(a as usize, b as usize) {
                    continue;
                }
                if triangle_distance(corners(&ta), corners(&tb)) < clearance_mm {
                    pairs.push([a.min(b), a.max(b)]);
                }
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    const FLAT: [P; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

    #[test]
    fn distances_of_hand_placed_triangles() {
        // Parallel, 0.25 above.
        let above = FLAT.map(|p| [p[0], p[1], 0.25]);
        assert!((triangle_distance(FLAT, above) - 0.25).abs() < 1e-12);
        // Piercing through the middle.
        let pierce = [[0.2, 0.2, -1.0], [0.2, 0.2, 1.0], [0.3, 0.3, 1.0]];
        assert_eq!(triangle_distance(FLAT, pierce), 0.0);
        // Beside the hypotenuse x + y = 1, at distance 0.1 in the plane.
        let s = 0.1 / std::f64::consts::SQRT_2;
        let beside = [[1.0 + s, s, 0.0], [s, 1.0 + s, 0.0], [1.0, 1.0, 0.0]];
        assert!((triangle_distance(FLAT, beside) - 0.1).abs() < 1e-12);
        // An edge crossing over the triangle, 0.5 above it.
        let crossed = [[0.25, -1.0, 0.5], [0.25, 1.0, 0.5], [5.0, 0.0, 9.0]];
        assert!((triangle_distance(FLAT, crossed) - 0.5).abs() < 1e-12);
        // Touching at one point of an edge, sharing no vertex.
        let touching = [[0.5, 0.0, 0.0], [0.5, -1.0, 0.0], [0.5, 0.0, -1.0]];
        assert_eq!(triangle_distance(FLAT, touching), 0.0);
    }

    #[test]
    fn a_mesh_with_a_sheet_through_another_is_found_and_shared_vertices_are_not() {
        let mesh = TriangleMesh {
            vertices: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.2, 0.2, -1.0],
                [0.2, 0.2, 1.0],
                [0.3, 0.3, 1.0],
            ],
            // 0 and 1 share an edge; 2 pierces 0.
            triangles: vec![[0, 1, 2], [1, 3, 2], [4, 5, 6]],
        };
        assert_eq!(self_intersections(&mesh, 1e-6), vec![[0, 2]]);
        // With a wide clearance the piercing sheet is near triangle 1 too.
        assert_eq!(self_intersections(&mesh, 0.5), vec![[0, 2], [1, 2]]);
    }
}
