//! `fusegraph bench phantom`: the generator's cost under each acquisition
//! condition against the ideal phantom, best of N wall times with the MRI,
//! calibration and view stages apart. Each phantom is written to a temporary
//! folder and removed.

use fusegraph_nodes::phantom::{
    Conditions, ConditionsPreset, MotionKind, PhantomConfig, PhantomSize, generate,
};
use std::fmt::Write as _;

/// The conditions timed: one at a time, then the presets.
fn cases() -> Vec<(&'static str, Conditions)> {
    let ideal = Conditions::default();
    let with = |f: &dyn Fn(&mut Conditions)| {
        let mut c = ideal.clone();
        f(&mut c);
        c
    };
    let lab = Conditions::preset(ConditionsPreset::Lab);
    vec![
        ("ideal", ideal.clone()),
        (
            "motion: sag 10 mm",
            with(&|c| {
                c.motion = MotionKind::Sag;
                c.motion_peak_mm = 10.0;
            }),
        ),
        ("two lamps (lab's)", {
            let (positions, intensities, kelvin) = (
                lab.lamp_positions_mm.clone(),
                lab.lamp_intensities.clone(),
                lab.lamp_kelvin.clone(),
            );
            with(&move |c| {
                c.lamp_positions_mm = positions.clone();
                c.lamp_intensities = intensities.clone();
                c.lamp_kelvin = kelvin.clone();
            })
        }),
        ("shadows", with(&|c| c.shadows = true)),
        ("specular 0.5", with(&|c| c.specular = 0.5)),
        (
            "defocus f/2 at 500 mm",
            with(&|c| {
                c.f_number = 2.0;
                c.focus_mm = 500.0;
            }),
        ),
        (
            "noise 5 DN + 5000 e",
            with(&|c| {
                c.read_noise_dn = 5.0;
                c.full_well_e = 5000.0;
            }),
        ),
        ("Bayer", with(&|c| c.bayer = true)),
        ("JPEG 90", with(&|c| c.jpeg_quality = 90)),
        ("skin texture 10 %", with(&|c| c.skin_texture_pct = 10.0)),
        (
            "distractors and the tool",
            with(&|c| {
                c.distractors = true;
                c.occluder = true;
            }),
        ),
        ("preset lab", lab.clone()),
        ("preset hard", Conditions::preset(ConditionsPreset::Hard)),
    ]
}

/// Times every case at `size`, best of `repeat`, and prints the table.
pub fn phantom(size: PhantomSize, repeat: usize) -> anyhow::Result<()> {
    let mut out = String::new();
    writeln!(
        out,
        "phantom.generate ({}), best of {repeat}: total and stages, ms; ratio to the ideal phantom",
        size.name()
    )?;
    writeln!(
        out,
        "| condition | total ms | MRI ms | calibration ms | views ms | total / ideal | views / ideal |"
    )?;
    writeln!(out, "| --- | ---: | ---: | ---: | ---: | ---: | ---: |")?;
    let mut ideal: Option<(f64, f64)> = None;
    for (name, conditions) in cases() {
        let config = PhantomConfig {
            size,
            conditions,
            ..PhantomConfig::default()
        };
        let mut best = [f64::MAX; 4];
        for _ in 0..repeat.max(1) {
            let dir = tempfile::tempdir()?;
            let t = std::time::Instant::now();
            let g = generate(&config, dir.path()).map_err(anyhow::Error::msg)?;
            let total = t.elapsed().as_secs_f64() * 1e3;
            for (b, v) in best
                .iter_mut()
                .zip([total, g.stage_ms[0], g.stage_ms[1], g.stage_ms[2]])
            {
                *b = b.min(v);
            }
        }
        let (total, views) = (best[0], best[3]);
        let (ideal_total, ideal_views) = *ideal.get_or_insert((total, views));
        writeln!(
            out,
            "| {name} | {:.0} | {:.0} | {:.0} | {:.0} | {:.2} | {:.2} |",
            total,
            best[1],
            best[2],
            views,
            total / ideal_total,
            views / ideal_views
        )?;
        eprintln!("{name}: {total:.0} ms");
    }
    print!("{out}");
    Ok(())
}
