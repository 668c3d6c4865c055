//! Features as a table (the value `stereo.features` hands to
//! `stereo.match_features`): one row per keypoint, its position, size, angle,
//! response and Laplacian sign, then its descriptor.

use super::{Descriptors, Features, Keypoint};
use fusegraph_engine::value::Table;

/// Keypoint columns of a feature table, before the descriptor columns.
const KEYPOINT_COLUMNS: [&str; 6] = [
    "x_px",
    "y_px",
    "size_px",
    "angle_deg",
    "response",
    "laplacian_sign",
];

/// A feature table: one row per keypoint, `KEYPOINT_COLUMNS` then `d00..d63`
/// (float descriptors; `laplacian_sign` +1 or -1) or `w0..w7` (the 256 bits as
/// eight 32-bit words, bit k of the descriptor in word k / 32; `laplacian_sign` 0).
pub fn features_to_table(f: &Features) -> Table {
    let binary = matches!(f.descriptors, Descriptors::Binary(_));
    let mut columns: Vec<String> = KEYPOINT_COLUMNS.iter().map(|c| c.to_string()).collect();
    if binary {
        columns.extend((0..8).map(|k| format!("w{k}")));
    } else {
        columns.extend((0..64).map(|k| format!("d{k:02}")));
    }
    let mut data = Vec::with_capacity(columns.len() * f.keypoints.len());
    for (i, kp) in f.keypoints.iter().enumerate() {
        let sign = match (binary, kp.laplacian_positive) {
            (true, _) => 0.0,
            (false, true) => 1.0,
            (false, false) => -1.0,
        };
        data.extend([
            kp.x_px as f64,
            kp.y_px as f64,
            kp.size_px as f64,
            (kp.angle_rad as f64).to_degrees(),
            kp.response as f64,
            sign,
        ]);
        match &f.descriptors {
            Descriptors::Float(d) => data.extend(d[i].iter().map(|&v| v as f64)),
            Descriptors::Binary(d) => {
                for word in d[i] {
                    data.extend([(word & 0xFFFF_FFFF) as f64, (word >> 32) as f64]);
                }
            }
        }
    }
    Table::new(columns, data).expect("rows are filled column by column")
}

/// Keypoints and descriptors back from a feature table; `what` names the input
/// in errors.
pub fn features_from_table(t: &Table, what: &str) -> Result<Features, String> {
    let n_kp = KEYPOINT_COLUMNS.len();
    if t.columns.len() < n_kp || t.columns[..n_kp].iter().ne(KEYPOINT_COLUMNS.iter()) {
        return Err(format!(
            "{what}: not a feature table from stereo.features (columns start {:?})",
            &t.columns[..t.columns.len().min(n_kp)]
        ));
    }
    let desc_cols = &t.columns[n_kp..];
    let float_names: Vec<String> = (0..64).map(|k| format!("d{k:02}")).collect();
    let binary_names: Vec<String> = (0..8).map(|k| format!("w{k}")).collect();
    let binary = if desc_cols == binary_names.as_slice() {
        true
    } else if desc_cols == float_names.as_slice() {
        false
    } else {
        return Err(format!(
            "{what}: descriptor columns are neither d00..d63 nor w0..w7"
        ));
    };
    let mut keypoints = Vec::with_capacity(t.row_count());
    let mut float = Vec::new();
    let mut bits = Vec::new();
    for r in 0..t.row_count() {
        let row = t.row(r);
        if let Some(c) = row.iter().position(|v| !v.is_finite()) {
            return Err(format!(
                "{what}: row {r}, column {} is not finite",
                t.columns[c]
            ));
        }
        keypoints.push(Keypoint {
            x_px: row[0] as f32,
            y_px: row[1] as f32,
            size_px: row[2] as f32,
            angle_rad: row[3].to_radians() as f32,
            response: row[4] as f32,
            laplacian_positive: row[5] > 0.0,
        });
        let d = &row[n_kp..];
        if binary {
            let mut words = [0u64; 4];
            for (k, &v) in d.iter().enumerate() {
                if v < 0.0 || v > u32::MAX as f64 || v.fract() != 0.0 {
                    return Err(format!("{what}: row {r}, w{k} = {v} is not a 32-bit word"));
                }
                words[k / 2] |= (v as u64) << (32 * (k % 2));
            }
            bits.push(words);
        } else {
            float.push(std::array::from_fn(|k| d[k] as f32));
        }
    }
    let descriptors = if binary {
        Descriptors::Binary(bits)
    } else {
        Descriptors::Float(float)
    };
    Ok(Features {
        keypoints,
        descriptors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_round_trip() {
        let kp = Keypoint {
            x_px: 1.5,
            y_px: 2.25,
            size_px: 15.0,
            angle_rad: 0.5,
            response: 0.01,
            laplacian_positive: true,
        };
        let f = Features {
            keypoints: vec![kp],
            descriptors: Descriptors::Binary(vec![[u64::MAX, 1, 1 << 63, 0xDEAD_BEEF_0000_0001]]),
        };
        let t = features_to_table(&f);
        assert_eq!(t.columns.len(), 14);
        assert_eq!(t.row(0)[5], 0.0, "FAST has no Laplacian sign");
        let back = features_from_table(&t, "t").unwrap();
        assert_eq!(back.descriptors, f.descriptors);
        assert!((back.keypoints[0].angle_rad - 0.5).abs() < 1e-6);
        let mut d = [0.0f32; 64];
        d[7] = 0.25;
        let f = Features {
            keypoints: vec![kp],
            descriptors: Descriptors::Float(vec![d]),
        };
        let t = features_to_table(&f);
        assert_eq!(t.columns[6], "d00");
        assert_eq!(t.row(0)[5], 1.0);
        assert_eq!(features_from_table(&t, "t").unwrap(), f);
        let other = Table::new(vec!["x_px".into()], vec![1.0]).unwrap();
        assert!(
            features_from_table(&other, "input `left`")
                .unwrap_err()
                .contains("input `left`")
        );
    }
}
