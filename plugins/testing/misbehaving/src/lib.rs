//! A plugin whose ops misbehave, one way each, for the host's tests: a panic,
//! an error, an output shorter than its shape, an output of another type
//! than declared, an undeclared output, and one well-behaved op.

use fusegraph_plugin_api::{Inputs, OpDecl, Outputs, Params, PluginOp, export_plugin};

/// Which misbehaviour.
pub struct Bad(&'static str);

impl PluginOp for Bad {
    fn declare(&self) -> OpDecl {
        OpDecl::new(&format!("bad.{}", self.0), 1, "misbehaves")
            .optional_input("x", &["Scalar"], "anything")
            .output("disparity", "Disparity", "a 4 x 2 map")
    }

    fn run(&self, _: &Inputs, _: &Params, out: &mut Outputs) -> Result<(), String> {
        match self.0 {
            "panic" => panic!("index 9 out of range in the matcher"),
            "fail" => return Err("refused: the pair is not rectified".into()),
            "short" => out.disparity("disparity", 4, 2, vec![1.0; 5]),
            "wrong_type" => out.scalar("disparity", 1.0),
            "undeclared" => {
                out.disparity("disparity", 4, 2, vec![1.0; 8]);
                out.scalar("extra", 2.0);
            }
            _ => {
                out.disparity("disparity", 4, 2, vec![1.5; 8]);
                out.metric("ok_count", 8.0);
                out.note("a note from the plugin");
            }
        }
        Ok(())
    }
}

export_plugin!(
    Bad("panic"),
    Bad("fail"),
    Bad("short"),
    Bad("wrong_type"),
    Bad("undeclared"),
    Bad("good"),
);
