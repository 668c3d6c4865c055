//! `report.html`: the run report as a page to look at, for any graph. Run
//! summary (graph, time, ran / cached / failed counts, failures with their
//! errors), reference figures beside ours when the graph names them, every
//! figure the nodes attached (PNG and SVG files beside it, point clouds in an
//! interactive WebGL view drawn by the page itself), a table of nodes, and
//! every metric. One self-contained file plus `figures/`: it opens from
//! `file://` with no server and no network.

use crate::figure::FigureData;
pub use crate::graph::Reference;
use crate::report::{NodeStatus, RunReport, figure_refs};
use std::fmt::Write;

/// Escapes text for HTML.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A number as the report shows it: 4 significant digits, `-` for NaN.
fn num(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    if v != 0.0 && (v.abs() >= 1e6 || v.abs() < 1e-3) {
        return format!("{v:.3e}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn status_name(s: NodeStatus) -> &'static str {
    match s {
        NodeStatus::Ran => "ran",
        NodeStatus::Cached => "cached",
        NodeStatus::Failed => "failed",
        NodeStatus::Skipped => "skipped",
    }
}

/// Base64 (standard alphabet, padded) of `bytes`, for data embedded in the page.
/// Appends `bytes` in base64 to `out`.
fn base64_into(bytes: &[u8], out: &mut String) {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode_string(bytes, out);
}

/// The page for `report`, with `references` beside our figures.
pub fn report_html(report: &RunReport, references: &[Reference]) -> String {
    // The point clouds' base64 is most of the page (megabytes): room for it
    // up front, not a string doubled and copied while it grows.
    let points_bytes: usize = report
        .nodes
        .iter()
        .flat_map(|(_, n)| n.figures.iter())
        .map(|f| match &f.data {
            FigureData::Points3d { xyz, rgb } => 4 * xyz.len() + rgb.len(),
            _ => 0,
        })
        .sum();
    let mut h = String::with_capacity(points_bytes.div_ceil(3) * 4 + (1 << 18));
    let count = |s: NodeStatus| report.nodes.iter().filter(|(_, n)| n.status == s).count();
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>{name}: fusegraph report</title><style>{STYLE}</style></head><body>\n\
         <h1>{name}</h1>\n<p class=\"summary\">{file} &middot; {ms} ms &middot; \
         <span class=\"ran\">{ran} ran</span>, <span class=\"cached\">{cached} cached</span>, \
         <span class=\"failed\">{failed} failed</span>, <span class=\"skipped\">{skipped} skipped</span> \
         &middot; <b>{verdict}</b></p>\n",
        name = esc(&report.graph),
        file = esc(&report.file),
        ms = num(report.total_ms),
        ran = count(NodeStatus::Ran),
        cached = count(NodeStatus::Cached),
        failed = count(NodeStatus::Failed),
        skipped = count(NodeStatus::Skipped),
        verdict = if report.succeeded() {
            "succeeded"
        } else {
            "FAILED"
        },
    );
    let failures: Vec<_> = report
        .nodes
        .iter()
        .filter(|(_, n)| matches!(n.status, NodeStatus::Failed | NodeStatus::Skipped))
        .collect();
    if !failures.is_empty() {
        h.push_str("<h2>Failures</h2>\n<ul class=\"failures\">\n");
        for (id, n) in failures {
            let _ = writeln!(
                h,
                "<li><b>{}</b> ({}, {}): {}</li>",
                esc(id),
                esc(&n.op),
                status_name(n.status),
                esc(n.error.as_deref().unwrap_or(""))
            );
        }
        h.push_str("</ul>\n");
    }
    let noted: Vec<_> = report
        .nodes
        .iter()
        .filter(|(_, n)| !n.notes.is_empty())
        .collect();
    if !noted.is_empty() {
        h.push_str("<h2>Warnings</h2>\n<ul class=\"notes\">\n");
        for (id, n) in noted {
            for note in n.notes.iter() {
                let _ = writeln!(h, "<li><b>{}</b>: {}</li>", esc(id), esc(note));
            }
        }
        h.push_str("</ul>\n");
    }
    let metrics = report.metrics();
    if !references.is_empty() {
        h.push_str(
            "<h2>Beside the reference</h2>\n<table><tr><th>metric</th><th>ours</th>\
             <th>reference</th><th>source</th></tr>\n",
        );
        for r in references {
            let ours = metrics.get(&r.metric).map_or("-".into(), |v| num(*v));
            let _ = writeln!(
                h,
                "<tr><td>{}</td><td class=\"n\">{ours}</td><td class=\"n\">{}</td><td>{}</td></tr>",
                esc(&r.metric),
                num(r.value),
                esc(&r.note)
            );
        }
        h.push_str("</table>\n");
    }
    let with_figures: Vec<_> = report
        .nodes
        .iter()
        .filter(|(_, n)| !n.figures.is_empty())
        .collect();
    if !with_figures.is_empty() {
        h.push_str("<h2>Figures</h2>\n");
        let mut views = 0;
        for (id, n) in with_figures {
            for (f, r) in n.figures.iter().zip(figure_refs(id, n)) {
                let _ = write!(h, "<figure id=\"fig-{}-{}\">", esc(id), esc(&f.name));
                match &f.data {
                    FigureData::Png(_) | FigureData::Svg(_) => {
                        let _ = write!(
                            h,
                            "<img src=\"{}\" alt=\"{}\">",
                            esc(&r.file),
                            esc(&f.caption)
                        );
                    }
                    FigureData::Points3d { xyz, rgb } => {
                        let floats: Vec<u8> = xyz.iter().flat_map(|v| v.to_le_bytes()).collect();
                        let _ = write!(
                            h,
                            "<canvas class=\"view3d\" id=\"view{views}\" width=\"900\" height=\"600\" \
                             data-xyz=\""
                        );
                        base64_into(&floats, &mut h);
                        h.push_str("\" data-rgb=\"");
                        base64_into(rgb, &mut h);
                        h.push_str(
                            "\"></canvas>\
                             <div class=\"hint\">drag to turn, wheel to zoom, double-click to reset</div>",
                        );
                        views += 1;
                    }
                }
                let _ = writeln!(
                    h,
                    "<figcaption><b>{}</b> &middot; {}</figcaption></figure>",
                    esc(id),
                    esc(&f.caption)
                );
            }
        }
    }
    h.push_str(
        "<h2>Nodes</h2>\n<table><tr><th>node</th><th>op</th><th>status</th>\
         <th>ms</th><th>metrics</th></tr>\n",
    );
    for (id, n) in &report.nodes {
        let shown: Vec<String> = n
            .metrics
            .iter()
            .take(4)
            .map(|(k, v)| format!("{}&nbsp;{}", esc(k), num(*v)))
            .collect();
        let more = n.metrics.len().saturating_sub(4);
        let _ = writeln!(
            h,
            "<tr class=\"{st}\"><td><a href=\"#node-{id}\">{id}</a></td><td>{op}</td>\
             <td>{st}</td><td class=\"n\">{ms}</td><td>{m}{more}</td></tr>",
            id = esc(id),
            op = esc(&n.op),
            st = status_name(n.status),
            ms = num(n.ms),
            m = shown.join(", "),
            more = if more > 0 {
                format!(" (+{more})")
            } else {
                String::new()
            }
        );
    }
    h.push_str("</table>\n");
    h.push_str("<h2>Every metric</h2>\n<table><tr><th>metric</th><th>value</th></tr>\n");
    for (id, n) in &report.nodes {
        for (k, v) in &n.metrics {
            let _ = writeln!(
                h,
                "<tr id=\"node-{id}\"><td>{id}.{}</td><td class=\"n\">{}</td></tr>",
                esc(k),
                num(*v),
                id = esc(id)
            );
        }
    }
    h.push_str("</table>\n");
    if !report.provenance.is_empty() {
        h.push_str("<h2>Provenance</h2>\n<table class=\"provenance\">\n");
        for (k, v) in &report.provenance {
            let text = match v {
                serde_json::Value::String(s) => s.clone(),
                other => other.to_string(),
            };
            let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(&text));
        }
        h.push_str("</table>\n");
    }
    let _ = write!(h, "<script>{VIEWER}</script>\n</body></html>\n");
    h
}

const STYLE: &str = "body{font:14px/1.4 system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}\
table{border-collapse:collapse;margin:.5em 0}td,th{border-bottom:1px solid #ddd;padding:2px 8px;text-align:left;vertical-align:top}\
td.n{text-align:right;font-variant-numeric:tabular-nums}.failed,.failed td{color:#b00}.skipped td{color:#888}\
.cached td{color:#555}.ran{color:#070}.cached{color:#555}figure{margin:1.5em 0}figure img{max-width:100%;border:1px solid #ccc}\
canvas.view3d{width:100%;max-width:900px;border:1px solid #ccc;background:#111;cursor:grab}.hint{color:#777;font-size:12px}";

/// A small WebGL viewer for the point clouds: orbit with the mouse, zoom with
/// the wheel. No library: a dozen lines of matrix code.
const VIEWER: &str = r#"
(function(){
// Errors are kept on the page too, so a headless browser can report them.
function note(m){document.body.dataset.errors=(document.body.dataset.errors||'')+m+'\n';}
window.addEventListener('error',e=>note(String(e.message)));
const cerr=console.error;console.error=function(){note(Array.from(arguments).join(' '));cerr.apply(console,arguments);};
function b64(s){const b=atob(s),u=new Uint8Array(b.length);for(let i=0;i<b.length;i++)u[i]=b.charCodeAt(i);return u;}
function mul(a,b){const r=new Float32Array(16);for(let i=0;i<4;i++)for(let j=0;j<4;j++){let s=0;for(let k=0;k<4;k++)s+=a[k*4+j]*b[i*4+k];r[i*4+j]=s;}return r;}
function rotX(t){const c=Math.cos(t),s=Math.sin(t);return new Float32Array([1,0,0,0, 0,c,s,0, 0,-s,c,0, 0,0,0,1]);}
function rotY(t){const c=Math.cos(t),s=Math.sin(t);return new Float32Array([c,0,-s,0, 0,1,0,0, s,0,c,0, 0,0,0,1]);}
function trans(x,y,z){return new Float32Array([1,0,0,0, 0,1,0,0, 0,0,1,0, x,y,z,1]);}
function persp(f,a,n,fa){const t=1/Math.tan(f/2);return new Float32Array([t/a,0,0,0, 0,t,0,0, 0,0,(fa+n)/(n-fa),-1, 0,0,2*fa*n/(n-fa),0]);}
function view(canvas){
  const xyz=new Float32Array(b64(canvas.dataset.xyz).buffer),rgb=b64(canvas.dataset.rgb),n=xyz.length/3;
  const gl=canvas.getContext('webgl',{preserveDrawingBuffer:true});
  if(!gl){note('no WebGL: the 3D view cannot be drawn');return;}
  if(n==0)return;
  let lo=[1e30,1e30,1e30],hi=[-1e30,-1e30,-1e30];
  for(let i=0;i<n;i++)for(let k=0;k<3;k++){const v=xyz[3*i+k];if(v<lo[k])lo[k]=v;if(v>hi[k])hi[k]=v;}
  const c=[0,1,2].map(k=>(lo[k]+hi[k])/2),r=Math.max(hi[0]-lo[0],hi[1]-lo[1],hi[2]-lo[2])/2||1;
  const sh=(t,src)=>{const s=gl.createShader(t);gl.shaderSource(s,src);gl.compileShader(s);return s;};
  const p=gl.createProgram();
  gl.attachShader(p,sh(gl.VERTEX_SHADER,'attribute vec3 a;attribute vec3 col;uniform mat4 m;varying vec3 v;void main(){gl_Position=m*vec4(a,1.0);gl_PointSize=2.0;v=col;}'));
  gl.attachShader(p,sh(gl.FRAGMENT_SHADER,'precision mediump float;varying vec3 v;void main(){gl_FragColor=vec4(v,1.0);}'));
  gl.linkProgram(p);gl.useProgram(p);
  const buf=(data,name,size,type,norm)=>{const b=gl.createBuffer();gl.bindBuffer(gl.ARRAY_BUFFER,b);gl.bufferData(gl.ARRAY_BUFFER,data,gl.STATIC_DRAW);const l=gl.getAttribLocation(p,name);gl.enableVertexAttribArray(l);gl.vertexAttribPointer(l,size,type,norm,0,0);};
  buf(xyz,'a',3,gl.FLOAT,false);buf(rgb,'col',3,gl.UNSIGNED_BYTE,true);
  const m=gl.getUniformLocation(p,'m');gl.enable(gl.DEPTH_TEST);
  let yaw=0,pitch=Math.PI,dist=3.2*r,drag=null;
  function draw(){
    gl.viewport(0,0,canvas.width,canvas.height);gl.clearColor(0.07,0.07,0.08,1);gl.clear(gl.COLOR_BUFFER_BIT|gl.DEPTH_BUFFER_BIT);
    let t=mul(trans(0,0,-dist),mul(rotX(pitch),mul(rotY(yaw),trans(-c[0],-c[1],-c[2]))));
    gl.uniformMatrix4fv(m,false,mul(persp(0.8,canvas.width/canvas.height,dist/50,dist*4),t));
    gl.drawArrays(gl.POINTS,0,n);
  }
  canvas.addEventListener('mousedown',e=>{drag=[e.clientX,e.clientY];});
  window.addEventListener('mouseup',()=>{drag=null;});
  window.addEventListener('mousemove',e=>{if(!drag)return;yaw+=(e.clientX-drag[0])*0.01;pitch+=(e.clientY-drag[1])*0.01;drag=[e.clientX,e.clientY];draw();});
  canvas.addEventListener('wheel',e=>{e.preventDefault();dist*=Math.exp(e.deltaY*0.001);draw();},{passive:false});
  canvas.addEventListener('dblclick',()=>{yaw=0;pitch=Math.PI;dist=3.2*r;draw();});
  draw();
  // How many pixels the points lit (for tests: a view that draws nothing is a fault).
  const px=new Uint8Array(4*canvas.width*canvas.height);
  gl.readPixels(0,0,canvas.width,canvas.height,gl.RGBA,gl.UNSIGNED_BYTE,px);
  let lit=0;for(let i=0;i<px.length;i+=4)if(px[i]>40||px[i+1]>40||px[i+2]>40)lit++;
  canvas.dataset.lit=lit;
}
document.querySelectorAll('canvas.view3d').forEach(view);
})();
"#;

#[cfg(test)]
mod tests {
    use super::*;

    fn base64(bytes: &[u8]) -> String {
        let mut out = String::new();
        base64_into(bytes, &mut out);
        out
    }
    use crate::figure::Figure;
    use crate::report::NodeReport;

    #[test]
    fn numbers_and_base64() {
        assert_eq!(num(0.123456), "0.1235");
        assert_eq!(num(1234.56), "1235");
        assert_eq!(num(3.0), "3");
        assert_eq!(num(f64::NAN), "-");
        assert_eq!(num(0.0), "0");
        assert_eq!(num(-2.5e-7), "-2.500e-7");
        assert_eq!(base64(b"Man"), "TWFu");
        assert_eq!(base64(b"Ma"), "TWE=");
        assert_eq!(base64(b"M"), "TQ==");
    }

    #[test]
    fn the_page_holds_summary_nodes_figures_and_metrics() {
        let node = |status, error: Option<&str>| NodeReport {
            op: "x.op".into(),
            status,
            ms: 12.5,
            key: "ab".into(),
            metrics: [("rmse_mm".to_string(), 0.61)].into(),
            error: error.map(String::from),
            notes: vec!["a.png: refused <blurred>".to_string()].into(),
            figures: vec![
                Figure {
                    name: "map".into(),
                    caption: "a <map>".into(),
                    data: FigureData::Png(vec![1, 2]),
                },
                Figure {
                    name: "cloud".into(),
                    caption: "points".into(),
                    data: FigureData::Points3d {
                        xyz: vec![0.0, 1.0, 2.0],
                        rgb: vec![255, 0, 0],
                    },
                },
            ]
            .into(),
        };
        let report = RunReport {
            graph: "g".into(),
            file: "g.toml".into(),
            nodes: vec![
                ("icp".into(), node(NodeStatus::Ran, None)),
                ("bad".into(), node(NodeStatus::Failed, Some("it broke"))),
            ],
            total_ms: 100.0,
            provenance: Default::default(),
        };
        let refs = [Reference {
            metric: "icp.rmse_mm".into(),
            value: 3.39,
            note: "the paper".into(),
        }];
        let page = report_html(&report, &refs);
        for needle in [
            "1 ran",
            "1 failed",
            "FAILED",
            "it broke",
            "<td class=\"n\">0.61</td><td class=\"n\">3.39</td><td>the paper</td>",
            "src=\"figures/icp.map.png\"",
            "a &lt;map&gt;",
            "canvas class=\"view3d\"",
            "icp.rmse_mm",
            "<h2>Warnings</h2>",
            "a.png: refused &lt;blurred&gt;",
        ] {
            assert!(page.contains(needle), "missing {needle:?}");
        }
    }
}
