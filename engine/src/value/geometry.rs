//! 3D geometry: [`Mesh`], [`PointCloud`], [`Markers`], and 2D [`Matches`].
//!
//! Coordinates are in mm, in the frame named by `frame` (e.g. `"mri_lps"` for DICOM
//! patient coordinates, `"camera_left"` for the left camera's frame, `"world"`).

use super::{ValueError, check_len};
use serde::Serialize;
use std::sync::Arc;

/// A triangle mesh: vertices (mm) and counter-clockwise triangles (outward normals).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Mesh {
    /// x, y, z of each vertex, mm.
    pub vertices: Arc<[f32]>,
    /// Three vertex indices per triangle.
    pub triangles: Arc<[u32]>,
    /// Unit normal per vertex, if known.
    pub normals: Option<Arc<[f32]>>,
    /// Coordinate frame of the vertices.
    pub frame: String,
}

impl Mesh {
    /// Checks buffer shapes and that every index names a vertex.
    pub fn new(
        vertices: impl Into<Arc<[f32]>>,
        triangles: impl Into<Arc<[u32]>>,
        normals: Option<Arc<[f32]>>,
        frame: impl Into<String>,
    ) -> Result<Self, ValueError> {
        let (vertices, triangles) = (vertices.into(), triangles.into());
        if vertices.len() % 3 != 0 || triangles.len() % 3 != 0 {
            return Err(ValueError("Mesh: buffers must hold triples".into()));
        }
        if let Some(n) = &normals {
            check_len("Mesh normals", n.len(), vertices.len())?;
        }
        let n_vertices = vertices.len() / 3;
        if let Some(&bad) = triangles.iter().find(|&&t| t as usize >= n_vertices) {
            return Err(ValueError(format!(
                "Mesh: triangle index {bad} out of range ({n_vertices} vertices)"
            )));
        }
        Ok(Mesh {
            vertices,
            triangles,
            normals,
            frame: frame.into(),
        })
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.vertices.len() / 3
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len() / 3
    }
}

/// A point cloud (mm) with optional RGB colours and unit normals.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointCloud {
    /// x, y, z of each point, mm.
    pub points: Arc<[f32]>,
    /// r, g, b of each point.
    pub colors: Option<Arc<[u8]>>,
    /// Unit normal of each point.
    pub normals: Option<Arc<[f32]>>,
    /// Coordinate frame of the points.
    pub frame: String,
}

impl PointCloud {
    /// Checks buffer shapes.
    pub fn new(
        points: impl Into<Arc<[f32]>>,
        colors: Option<Arc<[u8]>>,
        normals: Option<Arc<[f32]>>,
        frame: impl Into<String>,
    ) -> Result<Self, ValueError> {
        let points = points.into();
        if points.len() % 3 != 0 {
            return Err(ValueError("PointCloud: points must be triples".into()));
        }
        if let Some(c) = &colors {
            check_len("PointCloud colors", c.len(), points.len())?;
        }
        if let Some(n) = &normals {
            check_len("PointCloud normals", n.len(), points.len())?;
        }
        Ok(PointCloud {
            points,
            colors,
            normals,
            frame: frame.into(),
        })
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len() / 3
    }

    /// Whether the cloud has no point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The points whose `keep` is true (one flag per point), with their
    /// colours and normals.
    pub fn select(&self, keep: &[bool]) -> Result<PointCloud, ValueError> {
        check_len("PointCloud select flags", keep.len() * 3, self.points.len())?;
        let pick = |v: &[f32]| -> Vec<f32> {
            v.chunks_exact(3)
                .zip(keep)
                .filter(|(_, k)| **k)
                .flat_map(|(c, _)| c.iter().copied())
                .collect()
        };
        let colors = self.colors.as_ref().map(|c| {
            c.chunks_exact(3)
                .zip(keep)
                .filter(|(_, k)| **k)
                .flat_map(|(c, _)| c.iter().copied())
                .collect::<Vec<u8>>()
                .into()
        });
        PointCloud::new(
            pick(&self.points),
            colors,
            self.normals.as_ref().map(|n| pick(n).into()),
            self.frame.clone(),
        )
    }
}

/// Marker centres (mm) with an id each.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Markers {
    /// x, y, z of each marker centre, mm.
    pub positions_mm: Arc<[f64]>,
    /// One id per marker (e.g. a component label; not a correspondence).
    pub ids: Arc<[u32]>,
    /// Coordinate frame of the positions.
    pub frame: String,
}

impl Markers {
    /// Checks that there is one id per position.
    pub fn new(
        positions_mm: impl Into<Arc<[f64]>>,
        ids: impl Into<Arc<[u32]>>,
        frame: impl Into<String>,
    ) -> Result<Self, ValueError> {
        let (positions_mm, ids) = (positions_mm.into(), ids.into());
        check_len("Markers positions", positions_mm.len(), ids.len() * 3)?;
        Ok(Markers {
            positions_mm,
            ids,
            frame: frame.into(),
        })
    }

    /// Number of markers.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// Whether there is no marker.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// Corresponding keypoints in two images (px), with a matching score each.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Matches {
    /// x, y in the first (left) image, px.
    pub left_px: Arc<[f32]>,
    /// x, y in the second (right) image, px.
    pub right_px: Arc<[f32]>,
    /// Score per match (lower is better, e.g. descriptor distance).
    pub scores: Arc<[f32]>,
}

impl Matches {
    /// Checks that the three buffers describe the same number of matches.
    pub fn new(
        left_px: impl Into<Arc<[f32]>>,
        right_px: impl Into<Arc<[f32]>>,
        scores: impl Into<Arc<[f32]>>,
    ) -> Result<Self, ValueError> {
        let (left_px, right_px, scores) = (left_px.into(), right_px.into(), scores.into());
        check_len("Matches left", left_px.len(), scores.len() * 2)?;
        check_len("Matches right", right_px.len(), scores.len() * 2)?;
        Ok(Matches {
            left_px,
            right_px,
            scores,
        })
    }

    /// Number of matches.
    pub fn len(&self) -> usize {
        self.scores.len()
    }

    /// Whether there is no match.
    pub fn is_empty(&self) -> bool {
        self.scores.is_empty()
    }
}
