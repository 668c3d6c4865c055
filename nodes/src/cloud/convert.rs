//! Conversions between the engine's point cloud, mesh and marker values
//! (flat) and the algorithms' points and vectors (f64), frames unchanged.

use fusegraph_engine::OpError;
use fusegraph_engine::value::{Markers, Mesh, PointCloud};
use nalgebra::{Point3, Vector3};
use std::sync::Arc;

fn points_of(flat: &[f32]) -> Vec<Point3<f64>> {
    flat.chunks(3)
        .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect()
}

fn vectors_of(flat: &[f32]) -> Vec<Vector3<f64>> {
    flat.chunks(3)
        .map(|v| Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64))
        .collect()
}

/// A cloud's points, mm, in its frame.
pub(crate) fn cloud_points(c: &PointCloud) -> Vec<Point3<f64>> {
    points_of(&c.points)
}

/// A cloud's normals, when it has them.
pub(crate) fn cloud_normals(c: &PointCloud) -> Option<Vec<Vector3<f64>>> {
    c.normals.as_deref().map(vectors_of)
}

/// A mesh's vertices, mm, in its frame.
pub(crate) fn mesh_vertices(m: &Mesh) -> Vec<Point3<f64>> {
    points_of(&m.vertices)
}

/// A mesh's triangles (vertex indices).
pub(crate) fn mesh_triangles(m: &Mesh) -> Vec<[u32; 3]> {
    m.triangles.chunks(3).map(|t| [t[0], t[1], t[2]]).collect()
}

/// A mesh's vertex normals, when it has them.
pub(crate) fn mesh_normals(m: &Mesh) -> Option<Vec<Vector3<f64>>> {
    m.normals.as_deref().map(vectors_of)
}

/// A cloud value of `points` (mm, in `frame`), with normals and colours (3
/// bytes a point) when given.
pub(crate) fn make_cloud(
    points: &[Point3<f64>],
    normals: Option<&[Vector3<f64>]>,
    colors: Option<Arc<[u8]>>,
    frame: &str,
) -> Result<PointCloud, OpError> {
    let p: Vec<f32> = points
        .iter()
        .flat_map(|q| [q.x as f32, q.y as f32, q.z as f32])
        .collect();
    let n = normals.map(|n| {
        n.iter()
            .flat_map(|v| [v.x as f32, v.y as f32, v.z as f32])
            .collect::<Vec<f32>>()
            .into()
    });
    PointCloud::new(p, colors, n, frame).map_err(|e| OpError::invalid(e.0))
}

/// Markers' positions, mm, in their frame.
pub(crate) fn marker_points(m: &Markers) -> Vec<Point3<f64>> {
    m.positions_mm
        .chunks(3)
        .map(|c| Point3::new(c[0], c[1], c[2]))
        .collect()
}

/// A markers value of `points` (mm, in `frame`) with `ids`, one each.
pub(crate) fn markers_value(
    points: &[Point3<f64>],
    ids: Vec<u32>,
    frame: &str,
) -> Result<Markers, OpError> {
    let positions: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    Markers::new(positions, ids, frame).map_err(|e| OpError::invalid(e.0))
}
