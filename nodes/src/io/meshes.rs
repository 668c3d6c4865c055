//! Meshes and point clouds as files: binary PLY (vertices, normals or colours,
//! faces) and binary STL. STL goes through the stl_io crate; PLY is written
//! here because ply-rs-bw builds a map per vertex (slow for the hundreds of
//! thousands of vertices of an isosurface) and binary PLY is a dozen lines.

use fusegraph_engine::value::Mesh;
use std::io::Write;
use std::path::Path;

/// Writes a mesh or point cloud as binary little-endian PLY: float x y z per
/// vertex (`vertices`, 3 per vertex, in the caller's frame and unit), float
/// nx ny nz when `normals` are given, uchar red green blue when `colors` are,
/// and the `triangles` (3 vertex indices each; none for a cloud) as
/// uchar-counted int faces; `comment` goes into the header.
pub fn write_ply(
    path: &Path,
    vertices: &[f32],
    normals: Option<&[f32]>,
    colors: Option<&[u8]>,
    triangles: &[u32],
    comment: &str,
) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    let n = vertices.len() / 3;
    writeln!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {n}"
    )?;
    writeln!(w, "property float x\nproperty float y\nproperty float z")?;
    if normals.is_some() {
        writeln!(w, "property float nx\nproperty float ny\nproperty float nz")?;
    }
    if colors.is_some() {
        writeln!(
            w,
            "property uchar red\nproperty uchar green\nproperty uchar blue"
        )?;
    }
    writeln!(
        w,
        "element face {}\nproperty list uchar int vertex_indices\nend_header",
        triangles.len() / 3
    )?;
    for i in 0..n {
        for x in &vertices[3 * i..3 * i + 3] {
            w.write_all(&x.to_le_bytes())?;
        }
        if let Some(nrm) = normals {
            for x in &nrm[3 * i..3 * i + 3] {
                w.write_all(&x.to_le_bytes())?;
            }
        }
        if let Some(c) = colors {
            w.write_all(&c[3 * i..3 * i + 3])?;
        }
    }
    for t in triangles.chunks(3) {
        w.write_all(&[3u8])?;
        for &v in t {
            w.write_all(&(v as i32).to_le_bytes())?;
        }
    }
    w.flush()
}

/// Writes `mesh` as binary STL (facet normals from the vertex order).
pub fn write_stl(path: &Path, mesh: &Mesh) -> std::io::Result<()> {
    let v = |i: u32| {
        let i = i as usize * 3;
        [mesh.vertices[i], mesh.vertices[i + 1], mesh.vertices[i + 2]]
    };
    let triangles: Vec<stl_io::Triangle> = mesh
        .triangles
        .chunks(3)
        .map(|t| {
            let [a, b, c] = [v(t[0]), v(t[1]), v(t[2])];
            let (u, w) = (
                [0, 1, 2].map(|x| b[x] - a[x]),
                [0, 1, 2].map(|x| c[x] - a[x]),
            );
            let n = [
                u[1] * w[2] - u[2] * w[1],
                u[2] * w[0] - u[0] * w[2],
                u[0] * w[1] - u[1] * w[0],
            ];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-30);
            stl_io::Triangle {
                normal: stl_io::Normal::new(n.map(|x| x / len)),
                vertices: [a, b, c].map(stl_io::Vertex::new),
            }
        })
        .collect();
    let mut file = std::fs::File::create(path)?;
    stl_io::write_stl(&mut file, triangles.iter())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron() -> Mesh {
        Mesh::new(
            vec![
                0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0,
            ],
            vec![0u32, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3],
            None,
            "mri_lps",
        )
        .unwrap()
    }

    #[test]
    fn stl_reads_back() {
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("t.stl");
        write_stl(&path, &tetrahedron()).unwrap();
        let back = stl_io::read_stl(&mut std::fs::File::open(&path).unwrap()).unwrap();
        assert_eq!((back.vertices.len(), back.faces.len()), (4, 4));
        back.validate().unwrap();
    }

    #[test]
    fn ply_has_a_consistent_header_and_size() {
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("t.ply");
        let m = tetrahedron();
        write_ply(&path, &m.vertices, None, None, &m.triangles, "test").unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let header_end = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        let header = std::str::from_utf8(&bytes[..header_end]).unwrap();
        assert!(header.contains("element vertex 4") && header.contains("element face 4"));
        assert_eq!(bytes.len() - header_end, 4 * 12 + 4 * 13);
    }
}
