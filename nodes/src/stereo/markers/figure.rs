//! The markers found, drawn on the left image for the report.

/// `rgb` (w x h) at half size with a magenta ring and cross at each of
/// `centres` (full-size px), as PNG.
pub(crate) fn detections_png(
    rgb: &[u8],
    w: usize,
    h: usize,
    centres: &[(f64, f64)],
) -> Result<Vec<u8>, String> {
    let (hw, hh) = (w / 2, h / 2);
    let mut out = vec![0u8; hw * hh * 3];
    for y in 0..hh {
        for x in 0..hw {
            for c in 0..3 {
                let at = |dx: usize, dy: usize| rgb[((2 * y + dy) * w + 2 * x + dx) * 3 + c] as u16;
                out[(y * hw + x) * 3 + c] =
                    ((at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1) + 2) / 4) as u8;
            }
        }
    }
    let mut dot = |x: i64, y: i64| {
        if (0..hw as i64).contains(&x) && (0..hh as i64).contains(&y) {
            let i = (y as usize * hw + x as usize) * 3;
            out[i..i + 3].copy_from_slice(&[255, 0, 255]);
        }
    };
    for &(cx, cy) in centres {
        let (cx, cy) = (cx / 2.0, cy / 2.0);
        for t in 0..72 {
            let a = t as f64 * std::f64::consts::PI / 36.0;
            dot(
                (cx + 9.0 * a.cos()).round() as i64,
                (cy + 9.0 * a.sin()).round() as i64,
            );
        }
        for d in -3..=3 {
            dot(cx.round() as i64 + d, cy.round() as i64);
            dot(cx.round() as i64, cy.round() as i64 + d);
        }
    }
    crate::plot::png_bytes(&out, hw, hh)
}
