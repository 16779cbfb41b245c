//! Fixed-node lists: whitespace- or comma-separated 0-based node indices, `#` starts a comment.

use std::path::Path;

use super::MeshError;

/// Reads a node list and checks each index against `node_count` (the number of nodes in the
/// file's node order). Duplicates are removed; the result is sorted.
pub fn read_fixed_nodes(path: &Path, node_count: usize) -> Result<Vec<usize>, MeshError> {
    let text = std::fs::read_to_string(path).map_err(|e| MeshError::io(path, e))?;
    parse_fixed_nodes(&text, path, node_count)
}

pub fn parse_fixed_nodes(
    text: &str,
    path: &Path,
    node_count: usize,
) -> Result<Vec<usize>, MeshError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.split('#').next().unwrap_or("");
        for tok in l
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
        {
            let index: usize = tok.parse().map_err(|_| {
                MeshError::parse(path, line, format!("`{tok}` is not a 0-based node index"))
            })?;
            if index >= node_count {
                return Err(MeshError::FixedNodeOutOfRange {
                    path: path.into(),
                    line,
                    index,
                    nodes: node_count,
                });
            }
            out.push(index);
        }
    }
    out.sort_unstable();
    out.dedup();
    Ok(out)
}
