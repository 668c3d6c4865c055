//! `report.html` in a real browser (Debian's chromium, headless): the page
//! loads without console errors, the 3D view draws points, the figures are
//! there, and a screenshot is not blank. Skipped, with a message, where no
//! chromium is installed (`.ci/run` installs it where the machine lets it).

use super::common::chromium;
use fusegraph_engine::figure::{Figure, FigureData};
use fusegraph_engine::report::{NodeReport, NodeStatus, RunReport};
use fusegraph_engine::report_html::Reference;
use fusegraph_engine::session::write_report;
use std::path::Path;
use std::process::Command;

fn browse(browser: &str, page: &Path, extra: &[&str]) -> std::process::Output {
    let profile = tempfile::tempdir().unwrap();
    Command::new(browser)
        .args([
            "--headless=new",
            "--no-sandbox",
            "--disable-gpu",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--virtual-time-budget=10000",
            "--window-size=1200,1600",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .args(extra)
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("run the browser")
}

/// A report with every kind of figure: a PNG, an SVG and a point cloud.
fn sample_report() -> RunReport {
    let png = {
        let (w, h) = (64usize, 48usize);
        let rgb: Vec<u8> = (0..w * h)
            .flat_map(|i| [(i % w * 4) as u8, (i / w * 5) as u8, 128])
            .collect();
        let mut out = Vec::new();
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(&mut out),
            &rgb,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
        )
        .unwrap();
        out
    };
    // A sphere of coloured points.
    let (mut xyz, mut rgb) = (Vec::new(), Vec::new());
    for i in 0..4000 {
        let (t, p) = (i as f32 * 0.7, (i as f32 / 4000.0) * std::f32::consts::PI);
        xyz.extend([
            50.0 * p.sin() * t.cos(),
            50.0 * p.sin() * t.sin(),
            500.0 + 50.0 * p.cos(),
        ]);
        rgb.extend([255, (i % 255) as u8, 60]);
    }
    let node = |figures: Vec<Figure>| NodeReport {
        op: "test.op".into(),
        status: NodeStatus::Ran,
        ms: 1.0,
        key: "00".into(),
        metrics: [("rmse_mm".to_string(), 0.61)].into(),
        error: None,
        notes: Default::default(),
        figures: figures.into(),
    };
    RunReport {
        graph: "browser".into(),
        file: "browser.toml".into(),
        nodes: vec![
            (
                "maps".into(),
                node(vec![
                    Figure {
                        name: "map".into(),
                        caption: "a map".into(),
                        data: FigureData::Png(png),
                    },
                    Figure {
                        name: "plot".into(),
                        caption: "a plot".into(),
                        data: FigureData::Svg(
                            "<svg xmlns='http://www.w3.org/2000/svg' width='80' height='40'><rect width='80' height='40' fill='teal'/></svg>".into(),
                        ),
                    },
                ]),
            ),
            (
                "fused".into(),
                node(vec![Figure {
                    name: "cloud".into(),
                    caption: "a sphere".into(),
                    data: FigureData::Points3d { xyz, rgb },
                }]),
            ),
        ],
        total_ms: 2.0,
        provenance: Default::default(),
    }
}

#[test]
fn report_page_loads_draws_and_shows_its_figures_in_a_browser() {
    let Some(browser) = chromium() else {
        eprintln!("skipped: no chromium installed (apt install chromium)");
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let refs = [Reference {
        metric: "maps.rmse_mm".into(),
        value: 3.39,
        note: "the paper".into(),
    }];
    write_report(&sample_report(), &refs, out.path()).unwrap();
    let page = out.path().join("report.html");
    for f in [
        "figures/maps.map.png",
        "figures/maps.plot.svg",
        "report.json",
    ] {
        assert!(out.path().join(f).is_file(), "{f}");
    }
    let o = browse(browser, &page, &["--dump-dom"]);
    let dom = String::from_utf8_lossy(&o.stdout);
    assert!(
        dom.contains("<h1>browser</h1>"),
        "page did not load: {dom:.500}"
    );
    assert!(!dom.contains("data-errors="), "errors on the page: {dom}");
    let lit: usize = dom
        .split("data-lit=\"")
        .nth(1)
        .and_then(|s| s.split('"').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("the 3D view did not draw: {dom:.2000}"));
    assert!(lit > 500, "the 3D view lit only {lit} pixels");
    for needle in ["figures/maps.map.png", "figures/maps.plot.svg", "the paper"] {
        assert!(dom.contains(needle), "{needle} missing");
    }
    // And what a person would see is not a blank page.
    let shot = out.path().join("shot.png");
    let o = browse(
        browser,
        &page,
        &[&format!("--screenshot={}", shot.display())],
    );
    assert!(
        shot.is_file(),
        "no screenshot: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let img = image::open(&shot).unwrap().to_rgb8();
    let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    colours.sort_unstable();
    colours.dedup();
    assert!(
        colours.len() > 50,
        "screenshot nearly blank: {} colours",
        colours.len()
    );
}
