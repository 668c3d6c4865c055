//! What calling an op through the plugin ABI costs: `census.match` loaded from
//! the release cdylib, against the same algorithm as a built-in op, both run
//! through the engine's `Op::run` on one 800 x 600 grey pair, with 1 and 64
//! disparities (with one, the algorithm's time is small and the boundary's
//! cost shows).
//! Run `cargo build --release -p census-matcher` first (or set
//! CENSUS_PLUGIN to the library).

use census_matcher::census::{CensusParams, census_match};
use fusegraph_engine::op::{Inputs, Op, OpError, OpSpec, Outputs, RunCtx};
use fusegraph_engine::param::Params;
use fusegraph_engine::value::{Disparity, Image, Pixels, Value};
use fusegraph_engine::{Registry, ValueType};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The algorithm as a built-in op would wrap it.
struct BuiltIn(OpSpec);

impl Op for BuiltIn {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, _: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (l, r) = (inputs.get::<Image>("left")?, inputs.get::<Image>("right")?);
        let grey = |im: &Image| match &im.pixels {
            Pixels::U8(p) => p.to_vec(),
            Pixels::F32(_) => unreachable!("the bench passes u8"),
        };
        let max = *inputs.get::<f64>("max_disparity")? as i32;
        let p = CensusParams {
            census: [9, 7],
            aggregate: 7,
            range: [0, max],
            lr_max_diff_px: 1.0,
            uniqueness_pct: 5.0,
        };
        let d = census_match(&grey(&l), &grey(&r), l.width, l.height, &p);
        let valid = d.iter().filter(|v| !v.is_nan()).count();
        ctx.metric("coverage_pct", 100.0 * valid as f64 / d.len() as f64);
        let value = Disparity::new(l.width, l.height, d).map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new().with("disparity", value))
    }
}

fn random_pair(w: usize, h: usize, shift: usize) -> (Vec<u8>, Vec<u8>) {
    let mut s = 7u64;
    let base: Vec<u8> = (0..(w + shift) * h)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 56) as u8
        })
        .collect();
    let crop = |off: usize| -> Vec<u8> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| base[y * (w + shift) + x + off])
            .collect()
    };
    (crop(0), crop(shift))
}

fn time(op: &dyn Op, inputs: &Inputs, params: &Params, runs: usize) -> Vec<Duration> {
    (0..runs)
        .map(|_| {
            let mut ctx = RunCtx::new("match", std::path::Path::new("."));
            let start = Instant::now();
            let out = op.run(inputs, params, &mut ctx).expect("runs");
            let t = start.elapsed();
            assert!(out.0.contains_key("disparity"));
            t
        })
        .collect()
}

fn fastest_ms(t: Vec<Duration>) -> f64 {
    t.iter().min().expect("runs").as_secs_f64() * 1e3
}

fn main() {
    let lib = std::env::var_os("CENSUS_PLUGIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!(
                "../../target/release/{}census_matcher{}",
                std::env::consts::DLL_PREFIX,
                std::env::consts::DLL_SUFFIX
            ))
        });
    let mut registry = Registry::new();
    if let Err(e) = fusegraph_engine::plugin::load_plugin(&lib, &mut registry) {
        eprintln!("{e}\nbuild it first: cargo build --release -p census-matcher");
        std::process::exit(2);
    }
    let plugin = registry.get("census.match").expect("declared").clone();
    let builtin = BuiltIn(
        OpSpec::new("census.builtin", 1, "the same code built in")
            .input("left", &[ValueType::Image], "")
            .input("right", &[ValueType::Image], "")
            .output("disparity", ValueType::Disparity, ""),
    );
    let (w, h) = (800, 600);
    let (l, r) = random_pair(w, h, 20);
    let image = |px: Vec<u8>| Value::from(Image::new(w, h, 1, Pixels::U8(px.into())).unwrap());
    let mut inputs = Inputs::default();
    inputs.0.insert("left".into(), image(l));
    inputs.0.insert("right".into(), image(r));
    inputs
        .0
        .insert("min_disparity".into(), Value::Scalar(Arc::new(0.0)));
    let params = Params(
        plugin
            .spec()
            .params
            .iter()
            .map(|p| (p.name.clone(), p.default.clone().expect("defaults")))
            .collect::<BTreeMap<_, _>>(),
    );
    let runs = 15;
    for max in [0.0, 63.0] {
        inputs
            .0
            .insert("max_disparity".into(), Value::Scalar(Arc::new(max)));
        // Alternate, so both see the same machine state; the fastest of each.
        let (mut b, mut p) = (Vec::new(), Vec::new());
        for _ in 0..runs {
            b.extend(time(&builtin, &inputs, &params, 1));
            p.extend(time(plugin.as_ref(), &inputs, &params, 1));
        }
        let (b, p) = (fastest_ms(b), fastest_ms(p));
        println!(
            "census 9 x 7, 7 x 7 sums, {} disparities, {w} x {h} px, fastest of {runs}: built in {b:.2} ms, plugin {p:.2} ms, difference {:+.2} ms",
            max as usize + 1,
            p - b
        );
    }
}
