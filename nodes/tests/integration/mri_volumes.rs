//! graphs/mri.toml's volume sinks on the small phantom: the stretched volume
//! as NRRD and the Otsu mask as NIfTI, each with the loaded series' geometry.

use fusegraph_engine::Value;
use fusegraph_engine::cache::MemoryCache;
use fusegraph_engine::schedule::RunOptions;
use fusegraph_engine::session::{load_graph, run};
use fusegraph_nodes::io::{VoxelBuf, read_nifti, read_nrrd};
use fusegraph_nodes::mri::{TriangleMesh, self_intersections};
use std::path::{Path, PathBuf};

/// graphs/mri.toml with only the nodes `keep`, written into `dir`.
fn mri_graph_with(dir: &Path, keep: &[&str]) -> PathBuf {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../graphs/mri.toml"))
            .unwrap();
    let kept: Vec<&str> = text
        .split("\n[node.")
        .enumerate()
        .filter(|(i, section)| {
            *i == 0 || keep.iter().any(|k| section.starts_with(&format!("{k}]")))
        })
        .map(|(_, s)| s)
        .collect();
    let file = dir.join("mri.toml");
    std::fs::write(&file, kept.join("\n[node.")).unwrap();
    file
}

#[test]
fn mri_graph_writes_the_stretched_volume_and_the_otsu_mask_with_their_geometry() {
    // The graph up to Otsu and its two volume sinks (the rest is tested by the
    // CLI's end-to-end tests).
    let keep = [
        "phantom",
        "load",
        "stretch",
        "otsu",
        "write_stretched",
        "write_mask",
    ];
    let t = tempfile::tempdir().unwrap();
    let file = mri_graph_with(t.path(), &keep);
    let registry = fusegraph_nodes::builtin_registry();
    let graph = load_graph(&file, &["phantom.size=small".into()], &registry).unwrap();
    assert_eq!(graph.nodes.len(), keep.len());
    let options = RunOptions {
        out_dir: t.path().join("out"),
        cache: None,
        jobs: 0,
        progress: false,
        provenance: Default::default(),
        keep_outputs: true,
    };
    let outcome = run(&graph, &options, &MemoryCache::new()).unwrap();
    assert!(outcome.report.succeeded(), "{:?}", outcome.report);
    let output = |node: &str, port: &str| {
        let entry = outcome.results[graph.index_of(node).unwrap()]
            .as_ref()
            .unwrap();
        entry.outputs.0[port].clone()
    };
    let Value::Volume(stretched) = output("stretch", "volume") else {
        panic!("a volume")
    };
    let Value::Mask(mask) = output("otsu", "mask") else {
        panic!("a mask")
    };

    let (grid, voxels) = read_nrrd(&options.out_dir.join("mri_stretched.nrrd")).unwrap();
    assert_eq!(grid, stretched.grid, "NRRD keeps the affine exactly");
    assert_eq!(voxels, VoxelBuf::F32(stretched.data.to_vec()));

    let nifti = read_nifti(&options.out_dir.join("otsu_mask.nii.gz")).unwrap();
    assert_eq!(nifti.grid.dims, mask.grid.dims);
    let (a, b) = (&nifti.grid.voxel_to_patient, &mask.grid.voxel_to_patient);
    for r in 0..4 {
        for c in 0..4 {
            assert!((a[r][c] - b[r][c]).abs() < 1e-5, "{a:?} vs {b:?}");
        }
    }
    assert_eq!(nifti.voxels, VoxelBuf::U8(mask.data.to_vec()));
    let written = outcome.report.node("write_mask").unwrap();
    assert!(written.metrics["bytes"] > 0.0);
}

/// The skin surface of graphs/mri.toml on the small phantom (1.5 mm voxels),
/// with and without smoothing: closed, oriented, and no two triangles that
/// share no vertex come within 0.1 % of a voxel of each other. That is far
/// above f32 rounding (4e-6 mm at 100 mm); before marching cubes kept its
/// vertices off the lattice corners, 44 pairs came closer than 1e-3 mm, and
/// Open3D took such pairs for intersections.
#[test]
fn the_phantom_skin_surface_has_no_self_intersections() {
    let t = tempfile::tempdir().unwrap();
    let file = mri_graph_with(t.path(), &["phantom", "load", "stretch", "otsu", "surface"]);
    let registry = fusegraph_nodes::builtin_registry();
    let clearance_mm = 1e-3 * 1.5;
    for smoothing in [0, 10] {
        let sets = [
            "phantom.size=small".to_string(),
            format!("surface.smooth_iterations={smoothing}"),
        ];
        let graph = load_graph(&file, &sets, &registry).unwrap();
        let options = RunOptions {
            out_dir: t.path().join("out"),
            cache: None,
            jobs: 0,
            progress: false,
            provenance: Default::default(),
            keep_outputs: true,
        };
        let outcome = run(&graph, &options, &MemoryCache::new()).unwrap();
        assert!(outcome.report.succeeded(), "{:?}", outcome.report);
        let entry = outcome.results[graph.index_of("surface").unwrap()]
            .as_ref()
            .unwrap();
        let Value::Mesh(mesh) = &entry.outputs.0["mesh"] else {
            panic!("a mesh")
        };
        let mesh = TriangleMesh {
            vertices: mesh
                .vertices
                .chunks(3)
                .map(|v| [v[0], v[1], v[2]])
                .collect(),
            triangles: mesh
                .triangles
                .chunks(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect(),
        };
        assert!(mesh.triangles.len() > 10_000, "{}", mesh.triangles.len());
        assert!(mesh.is_closed_and_oriented());
        let pairs = self_intersections(&mesh, clearance_mm);
        assert!(
            pairs.is_empty(),
            "smoothing {smoothing}: {} pairs of triangles closer than {clearance_mm} mm, first {:?}",
            pairs.len(),
            &pairs[..pairs.len().min(3)]
        );
    }
}
