//! Voxel grids: [`Volume`], [`Mask`], [`Labels`] share one [`Grid`] geometry.

use super::{ValueError, check_len};
use serde::Serialize;
use std::sync::Arc;

/// The geometry of a voxel grid.
///
/// Voxel `(i, j, k)` (column, row, slice) is stored at `i + nx * (j + ny * k)`.
/// `voxel_to_patient` is a row-major 4x4 affine mapping voxel indices (of voxel
/// centres) to patient coordinates in mm, DICOM LPS.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Grid {
    /// Number of voxels along i, j, k.
    pub dims: [usize; 3],
    /// Voxel index -> patient LPS mm, row-major 4x4.
    pub voxel_to_patient: [[f64; 4]; 4],
}

impl Grid {
    /// A grid whose voxel axes are the patient axes, with the given spacing (mm)
    /// and the position (mm) of voxel (0, 0, 0).
    pub fn axis_aligned(dims: [usize; 3], spacing_mm: [f64; 3], origin_mm: [f64; 3]) -> Self {
        let mut m = [[0.0; 4]; 4];
        for a in 0..3 {
            m[a][a] = spacing_mm[a];
            m[a][3] = origin_mm[a];
        }
        m[3][3] = 1.0;
        Grid {
            dims,
            voxel_to_patient: m,
        }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// Whether the grid holds no voxel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear index of voxel `(i, j, k)`.
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel spacing along i, j, k in mm (lengths of the affine's columns).
    pub fn spacing_mm(&self) -> [f64; 3] {
        let m = &self.voxel_to_patient;
        std::array::from_fn(|c| (0..3).map(|r| m[r][c] * m[r][c]).sum::<f64>().sqrt())
    }

    /// Patient position (LPS mm) of a continuous voxel index.
    pub fn to_patient(&self, ijk: [f64; 3]) -> [f64; 3] {
        let m = &self.voxel_to_patient;
        std::array::from_fn(|r| m[r][0] * ijk[0] + m[r][1] * ijk[1] + m[r][2] * ijk[2] + m[r][3])
    }
}

macro_rules! grid_value {
    ($(#[$doc:meta])* $name:ident, $elem:ty) => {
        $(#[$doc])*
        #[derive(Debug, Clone, PartialEq, Serialize)]
        pub struct $name {
            /// Geometry of the grid.
            pub grid: Grid,
            /// One element per voxel, in [`Grid::index`] order.
            pub data: Arc<[$elem]>,
        }

        impl $name {
            /// Checks that `data` has one element per voxel.
            pub fn new(grid: Grid, data: impl Into<Arc<[$elem]>>) -> Result<Self, ValueError> {
                let data = data.into();
                check_len(stringify!($name), data.len(), grid.len())?;
                Ok($name { grid, data })
            }
        }
    };
}

grid_value!(
    /// Scalar voxel intensities (f32; units as the modality gives, e.g. MR signal).
    Volume,
    f32
);
grid_value!(
    /// A binary mask: 0 outside, 1 inside.
    Mask,
    u8
);
grid_value!(
    /// Connected-component labels: 0 is background, 1..=n the components.
    Labels,
    u32
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shape_is_checked() {
        let g = Grid::axis_aligned([2, 3, 4], [1.0, 1.0, 2.0], [0.0; 3]);
        assert!(Volume::new(g.clone(), vec![0.0f32; 24]).is_ok());
        let err = Mask::new(g, vec![0u8; 23]).unwrap_err();
        assert!(err.0.contains("23") && err.0.contains("24"), "{err}");
    }

    #[test]
    fn affine_maps_voxels_to_mm() {
        let g = Grid::axis_aligned([10, 10, 10], [0.5, 0.5, 2.0], [-10.0, 5.0, 1.0]);
        assert_eq!(g.to_patient([2.0, 4.0, 3.0]), [-9.0, 7.0, 7.0]);
        assert_eq!(g.spacing_mm(), [0.5, 0.5, 2.0]);
        assert_eq!(g.index(1, 2, 3), 1 + 10 * (2 + 10 * 3));
    }
}
