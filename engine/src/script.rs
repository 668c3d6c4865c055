//! Ops written in a scripting language (Python) rather than compiled into a
//! library: a graph's `[graph] python = ["ops.py"]` or the command line's
//! `--python ops.py` names the source files, and the [`ScriptHost`] that the
//! embedding program put in the [`Registry`] runs them and registers the ops
//! they declare. The `fusegraph` binary built by cargo embeds no Python, so
//! it has no host: a graph that names a script is then refused with
//! [`NO_SCRIPT_HOST`], and validation still names each op it cannot find.

use crate::registry::Registry;
pub use crate::registry::ScriptHost;

/// Why a script cannot be loaded in a program without a host.
pub const NO_SCRIPT_HOST: &str = "Python ops need the fusegraph Python package: \
`pip install ./python` in the fusegraph checkout, then run the graph with \
`python -m fusegraph run GRAPH.toml` (or `fusegraph.run(...)` from Python)";

/// `registry` with the scripts `files` loaded by its host; the error says
/// which file failed and why, or that there is no host.
pub fn load_scripts(files: &[std::path::PathBuf], registry: &mut Registry) -> Result<(), String> {
    if files.is_empty() {
        return Ok(());
    }
    let host = registry
        .script_host()
        .ok_or_else(|| format!("{}: {NO_SCRIPT_HOST}", files[0].display()))?;
    for file in files {
        host.load(file, registry)
            .map_err(|why| format!("{}: {why}", file.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    use std::path::Path;

    struct Recorder(Mutex<Vec<String>>);

    impl ScriptHost for Recorder {
        fn load(&self, file: &Path, _: &mut Registry) -> Result<Vec<String>, String> {
            let name = file.file_name().unwrap().to_string_lossy().into_owned();
            if name == "bad.py" {
                return Err("SyntaxError: invalid syntax (line 3)".into());
            }
            self.0.lock().unwrap().push(name);
            Ok(Vec::new())
        }
    }

    #[test]
    fn without_a_host_a_script_is_refused_with_what_to_do() {
        let mut registry = Registry::new();
        assert!(load_scripts(&[], &mut registry).is_ok());
        let err = load_scripts(&["/g/ops.py".into()], &mut registry).unwrap_err();
        assert!(err.starts_with("/g/ops.py: Python ops need"), "{err}");
        assert!(err.contains("pip install ./python"), "{err}");
    }

    #[test]
    fn the_host_loads_each_file_and_its_errors_name_the_file() {
        let host = Arc::new(Recorder(Mutex::new(Vec::new())));
        let mut registry = Registry::new();
        registry.set_script_host(host.clone());
        load_scripts(&["/g/a.py".into(), "/g/b.py".into()], &mut registry).unwrap();
        assert_eq!(*host.0.lock().unwrap(), ["a.py", "b.py"]);
        let err = load_scripts(&["/g/bad.py".into()], &mut registry).unwrap_err();
        assert_eq!(err, "/g/bad.py: SyntaxError: invalid syntax (line 3)");
    }
}
