//! The run report (`report.json`): per node its op, status, wall time, cache key,
//! metrics and error; and every metric flattened as `"node.metric"`.

use crate::figure::{Figure, FigureRef};
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::Arc;

/// What happened to a node in a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NodeStatus {
    /// The op ran.
    Ran,
    /// The result came from the cache.
    Cached,
    /// The op returned an error or panicked.
    Failed,
    /// Not run because an upstream node failed.
    Skipped,
}

/// One node's line in the report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NodeReport {
    /// Op name.
    pub op: String,
    /// What happened.
    pub status: NodeStatus,
    /// Wall time in ms (running, or loading from the cache).
    pub ms: f64,
    /// Cache key (hex).
    pub key: String,
    /// Metrics by name.
    pub metrics: BTreeMap<String, f64>,
    /// Why it failed or was skipped.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Warnings the op recorded: inputs refused, skipped or repaired, and why.
    #[serde(skip_serializing_if = "<[String]>::is_empty")]
    pub notes: Arc<[String]>,
    /// Figures it attached (listed in the JSON by [`RunReport::to_json`]).
    #[serde(skip)]
    pub figures: Arc<[Figure]>,
}

/// The report of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct RunReport {
    /// Graph name.
    pub graph: String,
    /// Graph file.
    pub file: String,
    /// Nodes in file order: (id, report).
    pub nodes: Vec<(String, NodeReport)>,
    /// Wall time of the whole run in ms.
    pub total_ms: f64,
    /// Where the run comes from (see [`crate::provenance`]).
    pub provenance: serde_json::Map<String, serde_json::Value>,
}

impl RunReport {
    /// Whether every node ran or was cached.
    pub fn succeeded(&self) -> bool {
        self.nodes
            .iter()
            .all(|(_, n)| matches!(n.status, NodeStatus::Ran | NodeStatus::Cached))
    }

    /// The report of node `id`.
    pub fn node(&self, id: &str) -> Option<&NodeReport> {
        self.nodes.iter().find(|(n, _)| n == id).map(|(_, r)| r)
    }

    /// How many notes (warnings) the nodes recorded, and by which nodes.
    pub fn note_counts(&self) -> Vec<(&str, usize)> {
        self.nodes
            .iter()
            .filter(|(_, n)| !n.notes.is_empty())
            .map(|(id, n)| (id.as_str(), n.notes.len()))
            .collect()
    }

    /// Every metric as `"node.metric"`.
    pub fn metrics(&self) -> BTreeMap<String, f64> {
        self.nodes
            .iter()
            .flat_map(|(id, n)| {
                n.metrics
                    .iter()
                    .map(move |(m, v)| (format!("{id}.{m}"), *v))
            })
            .collect()
    }

    /// The report as JSON (non-finite metrics become `null`).
    pub fn to_json(&self) -> serde_json::Value {
        let nodes: serde_json::Map<String, serde_json::Value> = self
            .nodes
            .iter()
            .map(|(id, n)| {
                let mut v = serde_json::to_value(n).expect("plain data");
                if !n.figures.is_empty() {
                    v["figures"] = serde_json::to_value(figure_refs(id, n)).expect("plain data");
                }
                (id.clone(), v)
            })
            .collect();
        serde_json::json!({
            "graph": self.graph,
            "file": self.file,
            "succeeded": self.succeeded(),
            "total_ms": self.total_ms,
            "warnings": self.note_counts().iter().map(|(_, n)| n).sum::<usize>(),
            "nodes": nodes,
            "metrics": self.metrics(),
            "provenance": self.provenance,
        })
    }
}

/// Where node `id`'s figures are written under the output folder.
pub fn figure_refs(id: &str, node: &NodeReport) -> Vec<FigureRef> {
    node.figures
        .iter()
        .map(|f| FigureRef {
            name: f.name.clone(),
            caption: f.caption.clone(),
            file: format!("figures/{}", f.file_name(id)),
        })
        .collect()
}
