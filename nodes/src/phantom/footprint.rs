//! A pixel's footprint on a plane, cut into the pieces a piecewise pattern
//! is constant (or linear) on: the exact mean of a chessboard over a pixel,
//! where supersampling counts a coverage in steps of one sample. The
//! footprint is the quadrilateral through the plane points of the rays
//! through the pixel's four corners; the pattern's cells are cut out of it
//! along axis-parallel lines (Sutherland-Hodgman against one line at a
//! time, which keeps a convex polygon convex).

/// A convex polygon in a plane's coordinates, its vertices in order (either
/// way round).
#[derive(Debug, Clone, PartialEq)]
pub struct Polygon(pub Vec<[f64; 2]>);

impl Polygon {
    /// The area (positive) and centroid. A degenerate polygon has area 0
    /// and its first vertex (or the origin) as centroid.
    pub fn area_centroid(&self) -> (f64, [f64; 2]) {
        let v = &self.0;
        let Some(&first) = v.first() else {
            return (0.0, [0.0; 2]);
        };
        // Relative to the first vertex, so that far-off coordinates lose
        // no precision in the cross products.
        let (mut twice_area, mut cx, mut cy) = (0.0, 0.0, 0.0);
        for i in 0..v.len() {
            let a = [v[i][0] - first[0], v[i][1] - first[1]];
            let j = (i + 1) % v.len();
            let b = [v[j][0] - first[0], v[j][1] - first[1]];
            let cross = a[0] * b[1] - b[0] * a[1];
            twice_area += cross;
            cx += (a[0] + b[0]) * cross;
            cy += (a[1] + b[1]) * cross;
        }
        if twice_area == 0.0 {
            return (0.0, first);
        }
        (
            0.5 * twice_area.abs(),
            [
                first[0] + cx / (3.0 * twice_area),
                first[1] + cy / (3.0 * twice_area),
            ],
        )
    }

    /// The parts below and above the line where coordinate `axis` (0: x,
    /// 1: y) equals `at` (either may be empty).
    pub fn split(&self, axis: usize, at: f64) -> (Polygon, Polygon) {
        let v = &self.0;
        let (mut below, mut above) = (Vec::new(), Vec::new());
        for i in 0..v.len() {
            let (a, b) = (v[i], v[(i + 1) % v.len()]);
            let (a_below, b_below) = (a[axis] < at, b[axis] < at);
            if a_below {
                below.push(a);
            } else {
                above.push(a);
            }
            if a_below != b_below {
                let t = (at - a[axis]) / (b[axis] - a[axis]);
                let mut cut = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
                cut[axis] = at;
                below.push(cut);
                above.push(cut);
            }
        }
        (Polygon(below), Polygon(above))
    }

    /// The lowest and highest value of coordinate `axis` over the vertices.
    pub fn range(&self, axis: usize) -> (f64, f64) {
        self.0
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p[axis]), hi.max(p[axis]))
            })
    }
}

/// The pieces of `polygon` between the lines x = each of `cuts_x` and y =
/// each of `cuts_y`, as (area, centroid); pieces of no area are left out.
pub fn pieces(polygon: Polygon, cuts_x: &[f64], cuts_y: &[f64]) -> Vec<(f64, [f64; 2])> {
    let mut parts = vec![polygon];
    for (axis, cuts) in [(0, cuts_x), (1, cuts_y)] {
        for &at in cuts {
            let mut cut = Vec::with_capacity(parts.len() + 1);
            for p in parts {
                let (lo, hi) = p.range(axis);
                if at <= lo || at >= hi {
                    cut.push(p);
                } else {
                    let (below, above) = p.split(axis, at);
                    cut.extend([below, above]);
                }
            }
            parts = cut;
        }
    }
    parts
        .iter()
        .map(Polygon::area_centroid)
        .filter(|(area, _)| *area > 0.0)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x0: f64, y0: f64, side: f64) -> Polygon {
        Polygon(vec![
            [x0, y0],
            [x0 + side, y0],
            [x0 + side, y0 + side],
            [x0, y0 + side],
        ])
    }

    #[test]
    fn area_and_centroid_by_hand() {
        let (area, c) = square(2.0, -1.0, 2.0).area_centroid();
        assert!((area - 4.0).abs() < 1e-12 && (c[0] - 3.0).abs() < 1e-12 && c[1].abs() < 1e-12);
        // A right triangle, clockwise: area 6, centroid at a third of the legs.
        let (area, c) = Polygon(vec![[0.0, 0.0], [0.0, 4.0], [3.0, 0.0]]).area_centroid();
        assert!((area - 6.0).abs() < 1e-12, "{area}");
        assert!(
            (c[0] - 1.0).abs() < 1e-12 && (c[1] - 4.0 / 3.0).abs() < 1e-12,
            "{c:?}"
        );
        assert_eq!(Polygon(vec![]).area_centroid().0, 0.0);
        assert_eq!(Polygon(vec![[1.0, 1.0], [2.0, 2.0]]).area_centroid().0, 0.0);
    }

    #[test]
    fn a_split_square_keeps_its_area_on_both_sides() {
        let (left, right) = square(0.0, 0.0, 1.0).split(0, 0.3);
        let ((a, ca), (b, cb)) = (left.area_centroid(), right.area_centroid());
        assert!(
            (a - 0.3).abs() < 1e-12 && (b - 0.7).abs() < 1e-12,
            "{a} {b}"
        );
        assert!((ca[0] - 0.15).abs() < 1e-12 && (cb[0] - 0.65).abs() < 1e-12);
        assert!((ca[1] - 0.5).abs() < 1e-12 && (cb[1] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn pieces_of_a_tilted_quad_tile_it() {
        // A quad across a grid corner, cut along x = 0 and y = 0 and a
        // line that misses it.
        let quad = Polygon(vec![[-0.4, -0.2], [0.5, -0.35], [0.45, 0.6], [-0.3, 0.4]]);
        let (whole, _) = quad.area_centroid();
        let parts = pieces(quad, &[0.0, 7.0], &[0.0]);
        assert_eq!(parts.len(), 4);
        let total: f64 = parts.iter().map(|p| p.0).sum();
        assert!((total - whole).abs() < 1e-12, "{total} vs {whole}");
        // One piece in each quadrant.
        let mut quadrants: Vec<(bool, bool)> = parts
            .iter()
            .map(|(_, c)| (c[0] > 0.0, c[1] > 0.0))
            .collect();
        quadrants.sort();
        assert_eq!(
            quadrants,
            vec![(false, false), (false, true), (true, false), (true, true)]
        );
    }

    #[test]
    fn far_off_coordinates_keep_their_precision() {
        let (area, c) = square(1e6, -1e6, 0.001).area_centroid();
        assert!((area / 1e-6 - 1.0).abs() < 1e-6, "{area}");
        assert!((c[0] - (1e6 + 0.0005)).abs() < 1e-9, "{c:?}");
    }
}
