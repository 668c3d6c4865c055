//! graphs/mri.toml's volume sinks on the small phantom: the stretched volume
//! as NRRD and the Otsu mask as NIfTI, each with the loaded series' geometry.

use fusegraph_engine::Value;
use fusegraph_engine::cache::MemoryCache;
use fusegraph_engine::schedule::RunOptions;
use fusegraph_engine::session::{load_graph, run};
use fusegraph_nodes::io::{VoxelBuf, read_nifti, read_nrrd};
use std::path::Path;

#[test]
fn mri_graph_writes_the_stretched_volume_and_the_otsu_mask_with_their_geometry() {
    // The graph up to Otsu and its two volume sinks (the rest is tested by the
    // CLI's end-to-end tests).
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../graphs/mri.toml"))
            .unwrap();
    let keep = [
        "phantom]",
        "load]",
        "stretch]",
        "otsu]",
        "write_stretched]",
        "write_mask]",
    ];
    let kept: Vec<&str> = text
        .split("\n[node.")
        .enumerate()
        .filter(|(i, section)| *i == 0 || keep.iter().any(|k| section.starts_with(k)))
        .map(|(_, s)| s)
        .collect();
    let t = tempfile::tempdir().unwrap();
    let file = t.path().join("mri.toml");
    std::fs::write(&file, kept.join("\n[node.")).unwrap();
    let registry = fusegraph_nodes::builtin_registry();
    let graph = load_graph(&file, &["phantom.size=small".into()], &registry).unwrap();
    assert_eq!(graph.nodes.len(), keep.len());
    let options = RunOptions {
        out_dir: t.path().join("out"),
        cache: None,
        jobs: 0,
        progress: false,
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
