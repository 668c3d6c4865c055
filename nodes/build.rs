//! Writes the built-in ops' code fingerprints (see `build/fingerprint.rs`)
//! for their cache keys into `$OUT_DIR/code_fingerprints.rs`.

#[path = "build/fingerprint.rs"]
mod fingerprint;

use std::path::Path;

fn read_sources(root: &Path, dir: &Path, out: &mut fingerprint::Sources) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("a directory entry").path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            read_sources(root, &path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            let rel = path.strip_prefix(root).expect("under src");
            let rel: Vec<String> = rel
                .iter()
                .map(|c| c.to_string_lossy().into_owned())
                .collect();
            let text = std::fs::read_to_string(&path)
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            out.insert(rel.join("/"), text);
        }
    }
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    println!("cargo:rerun-if-changed=src");
    println!("cargo:rerun-if-changed=build");
    let mut sources = fingerprint::Sources::new();
    read_sources(&root, &root, &mut sources);
    let mut code = String::from(
        "/// Each built-in op's code fingerprint (blake3, hex), by op name.\n\
         pub const CODE_FINGERPRINTS: &[(&str, &str)] = &[\n",
    );
    for (op, hash) in fingerprint::fingerprints(&sources) {
        code.push_str(&format!("    ({op:?}, {hash:?}),\n"));
    }
    code.push_str("];\n");
    let out = Path::new(&std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"))
        .join("code_fingerprints.rs");
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("{}: {e}", out.display()));
}
