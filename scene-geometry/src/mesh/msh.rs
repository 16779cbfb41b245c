//! Gmsh MSH reader: 4.1 and 2.2 ASCII, linear tetrahedra (element type 4). Other element
//! types are skipped except boundary triangles (type 2), which are kept for reference.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::Point3;

use super::{MeshError, Sliver, TetMesh};

const TET4: i64 = 4;
const TRI3: i64 = 2;

/// A tet mesh as read from a Gmsh file.
#[derive(Debug, Clone)]
pub struct MshMesh {
    /// Positively oriented, unused nodes dropped.
    pub mesh: TetMesh,
    /// For each mesh node, its 0-based position in the file's node order (what node lists
    /// such as the study's fixed-node file refer to).
    pub file_index: Vec<usize>,
    /// Triangles (type 2) whose nodes are all mesh nodes, in mesh-node indices, as written.
    pub triangles: Vec<[usize; 3]>,
    /// Thin but valid tets (each also reported through `tracing::warn`).
    pub slivers: Vec<Sliver>,
    /// How many tets were negatively oriented in the file and have been reordered.
    pub reordered: usize,
    /// File format version (4.1 or 2.2).
    pub version: String,
}

impl MshMesh {
    /// Maps 0-based file node positions (as in a node list) to mesh-node indices.
    pub fn mesh_index_of_file(&self, file_pos: usize) -> Option<usize> {
        self.file_index.binary_search(&file_pos).ok()
    }
}

pub fn read_msh(path: &Path) -> Result<MshMesh, MeshError> {
    let text = std::fs::read(path).map_err(|e| MeshError::io(path, e))?;
    let text = String::from_utf8(text).map_err(|e| MeshError::Unsupported {
        path: path.into(),
        problem: format!("not UTF-8/ASCII text (binary MSH is not supported): {e}"),
    })?;
    parse_msh(&text, path)
}

/// Lines of the file with 1-based numbers, skipping blank lines.
struct Cursor<'a> {
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
    path: PathBuf,
    line: usize,
}

impl<'a> Cursor<'a> {
    fn next(&mut self) -> Option<(usize, &'a str)> {
        for (i, l) in self.lines.by_ref() {
            let l = l.trim();
            if !l.is_empty() {
                self.line = i + 1;
                return Some((i + 1, l));
            }
        }
        None
    }
    fn expect(&mut self, what: &str) -> Result<(usize, &'a str), MeshError> {
        let at = self.line;
        self.next().ok_or_else(|| {
            MeshError::parse(
                &self.path,
                at,
                format!("unexpected end of file, expected {what}"),
            )
        })
    }
    fn err(&self, line: usize, problem: impl Into<String>) -> MeshError {
        MeshError::parse(&self.path, line, problem)
    }
    fn ints(&self, line: usize, text: &str, what: &str) -> Result<Vec<i64>, MeshError> {
        text.split_whitespace()
            .map(|t| {
                t.parse::<i64>()
                    .map_err(|_| self.err(line, format!("{what}: `{t}` is not an integer")))
            })
            .collect()
    }
    fn skip_section(&mut self, name: &str) -> Result<(), MeshError> {
        let end = format!("$End{}", &name[1..]);
        let start = self.line;
        while let Some((_, l)) = self.next() {
            if l == end {
                return Ok(());
            }
        }
        Err(self.err(start, format!("section {name} has no {end}")))
    }
}

struct RawNodes {
    positions: Vec<Point3<f64>>,
    tag_to_index: HashMap<i64, usize>,
}

struct RawElement {
    tag: i64,
    line: usize,
    kind: i64,
    nodes: Vec<i64>,
}

pub fn parse_msh(text: &str, path: &Path) -> Result<MshMesh, MeshError> {
    let mut cur = Cursor {
        lines: text.lines().enumerate(),
        path: path.to_path_buf(),
        line: 0,
    };
    let mut version: Option<String> = None;
    let mut nodes: Option<RawNodes> = None;
    let mut elements: Option<Vec<RawElement>> = None;
    while let Some((line, l)) = cur.next() {
        match l {
            "$MeshFormat" => {
                let (fl, f) = cur.expect("the format line")?;
                let parts: Vec<&str> = f.split_whitespace().collect();
                if parts.len() < 3 {
                    return Err(cur.err(fl, "format line needs `version file-type data-size`"));
                }
                let v = parts[0];
                if v != "4.1" && !v.starts_with("2.") {
                    return Err(MeshError::Unsupported {
                        path: path.into(),
                        problem: format!("MSH version {v} (supported: 4.1, 2.2)"),
                    });
                }
                if parts[1] != "0" {
                    return Err(MeshError::Unsupported {
                        path: path.into(),
                        problem: "binary MSH (only ASCII is supported)".into(),
                    });
                }
                version = Some(v.to_string());
                let (el, e) = cur.expect("$EndMeshFormat")?;
                if e != "$EndMeshFormat" {
                    return Err(cur.err(el, format!("expected $EndMeshFormat, found `{e}`")));
                }
            }
            "$Nodes" => {
                let v = version
                    .as_deref()
                    .ok_or_else(|| MeshError::MissingSection {
                        path: path.into(),
                        section: "$MeshFormat",
                    })?;
                nodes = Some(if v == "4.1" {
                    nodes_41(&mut cur)?
                } else {
                    nodes_22(&mut cur)?
                });
            }
            "$Elements" => {
                let v = version
                    .as_deref()
                    .ok_or_else(|| MeshError::MissingSection {
                        path: path.into(),
                        section: "$MeshFormat",
                    })?;
                elements = Some(if v == "4.1" {
                    elements_41(&mut cur)?
                } else {
                    elements_22(&mut cur)?
                });
            }
            s if s.starts_with("$End") => {
                return Err(cur.err(line, format!("unmatched `{s}`")));
            }
            s if s.starts_with('$') => cur.skip_section(s)?,
            s => return Err(cur.err(line, format!("unexpected text outside a section: `{s}`"))),
        }
    }
    let version = version.ok_or_else(|| MeshError::MissingSection {
        path: path.into(),
        section: "$MeshFormat",
    })?;
    let nodes = nodes.ok_or_else(|| MeshError::MissingSection {
        path: path.into(),
        section: "$Nodes",
    })?;
    let elements = elements.ok_or_else(|| MeshError::MissingSection {
        path: path.into(),
        section: "$Elements",
    })?;

    let resolve = |e: &RawElement, t: i64| -> Result<usize, MeshError> {
        nodes
            .tag_to_index
            .get(&t)
            .copied()
            .ok_or(MeshError::NodeOutOfRange {
                path: path.into(),
                line: e.line,
                element: e.tag.max(0) as usize,
                tag: t,
            })
    };
    let mut tets = Vec::new();
    let mut tet_lines = Vec::new();
    let mut tet_tags = Vec::new();
    let mut tris_file = Vec::new();
    for e in &elements {
        match e.kind {
            TET4 => {
                if e.nodes.len() != 4 {
                    return Err(cur.err(
                        e.line,
                        format!(
                            "element {}: tetrahedron needs 4 nodes, has {}",
                            e.tag,
                            e.nodes.len()
                        ),
                    ));
                }
                let mut t = [0usize; 4];
                for k in 0..4 {
                    t[k] = resolve(e, e.nodes[k])?;
                }
                let mut s = t;
                s.sort_unstable();
                if s.windows(2).any(|w| w[0] == w[1]) {
                    return Err(MeshError::ZeroVolume {
                        path: path.into(),
                        line: e.line,
                        element: e.tag.max(0) as usize,
                        volume: 0.0,
                        edge: 0.0,
                    });
                }
                tets.push(t);
                tet_lines.push(e.line);
                tet_tags.push(e.tag.max(0) as usize);
            }
            TRI3 if e.nodes.len() == 3 => {
                let mut t = [0usize; 3];
                for k in 0..3 {
                    t[k] = resolve(e, e.nodes[k])?;
                }
                tris_file.push(t);
            }
            _ => {
                // Points, lines, other element types: still check their node tags.
                for &n in &e.nodes {
                    resolve(e, n)?;
                }
            }
        }
    }
    if tets.is_empty() {
        return Err(MeshError::invalid(
            path,
            "no tetrahedra (element type 4) in $Elements",
        ));
    }
    let mut mesh = TetMesh {
        nodes: nodes.positions,
        tets,
    };
    let (slivers, reordered) = mesh.validate(path, Some(&tet_lines), Some(&tet_tags))?;
    let file_index = mesh.drop_unused_nodes();
    let mut new_index = vec![usize::MAX; file_index.last().map_or(0, |&l| l + 1)];
    for (new, &old) in file_index.iter().enumerate() {
        new_index[old] = new;
    }
    let triangles = tris_file
        .into_iter()
        .filter_map(|t| {
            let m = t.map(|i| new_index.get(i).copied().unwrap_or(usize::MAX));
            m.iter().all(|&i| i != usize::MAX).then_some(m)
        })
        .collect();
    Ok(MshMesh {
        mesh,
        file_index,
        triangles,
        slivers,
        reordered,
        version,
    })
}

/// Capacity to reserve for a count read from a header: a corrupt header must not make us
/// allocate (or abort on) a huge buffer before the content proves it.
fn reserve(count: i64) -> usize {
    count.clamp(0, 1 << 12) as usize
}

fn parse_coord(cur: &Cursor, line: usize, t: &str, node: i64) -> Result<f64, MeshError> {
    let v: f64 = t
        .parse()
        .map_err(|_| cur.err(line, format!("node {node}: `{t}` is not a number")))?;
    if !v.is_finite() {
        return Err(MeshError::NonFiniteCoordinate {
            path: cur.path.clone(),
            line,
            node: node.max(0) as usize,
            value: v,
        });
    }
    Ok(v)
}

fn push_node(
    cur: &Cursor,
    out: &mut RawNodes,
    line: usize,
    tag: i64,
    xyz: &[&str],
) -> Result<(), MeshError> {
    if xyz.len() < 3 {
        return Err(cur.err(line, format!("node {tag}: needs x y z")));
    }
    let p = Point3::new(
        parse_coord(cur, line, xyz[0], tag)?,
        parse_coord(cur, line, xyz[1], tag)?,
        parse_coord(cur, line, xyz[2], tag)?,
    );
    if out.tag_to_index.insert(tag, out.positions.len()).is_some() {
        return Err(cur.err(line, format!("node tag {tag} defined twice")));
    }
    out.positions.push(p);
    Ok(())
}

fn end_section(cur: &mut Cursor, end: &str) -> Result<(), MeshError> {
    let (l, t) = cur.expect(end)?;
    if t != end {
        return Err(cur.err(l, format!("expected {end}, found `{t}` (counts in the section header do not match its content)")));
    }
    Ok(())
}

fn nodes_41(cur: &mut Cursor) -> Result<RawNodes, MeshError> {
    let (hl, h) = cur.expect("the $Nodes header")?;
    let head = cur.ints(hl, h, "$Nodes header")?;
    if head.len() != 4 || head.iter().any(|&v| v < 0) {
        return Err(cur.err(
            hl,
            "$Nodes header must be `numEntityBlocks numNodes minNodeTag maxNodeTag`",
        ));
    }
    let mut out = RawNodes {
        positions: Vec::with_capacity(reserve(head[1])),
        tag_to_index: HashMap::with_capacity(reserve(head[1])),
    };
    for _ in 0..head[0] {
        let (bl, b) = cur.expect("a node entity block header")?;
        let block = cur.ints(bl, b, "node block header")?;
        if block.len() != 4 || block[3] < 0 {
            return Err(cur.err(
                bl,
                "node block header must be `entityDim entityTag parametric numNodesInBlock`",
            ));
        }
        let n = block[3] as usize;
        let mut tags = Vec::with_capacity(reserve(n as i64));
        for _ in 0..n {
            let (tl, t) = cur.expect("a node tag")?;
            let v = cur.ints(tl, t, "node tag")?;
            if v.len() != 1 {
                return Err(cur.err(tl, "expected one node tag per line"));
            }
            tags.push(v[0]);
        }
        for &tag in &tags {
            let (cl, c) = cur.expect("node coordinates")?;
            let parts: Vec<&str> = c.split_whitespace().collect();
            push_node(cur, &mut out, cl, tag, &parts)?;
        }
    }
    if out.positions.len() != head[1] as usize {
        return Err(cur.err(
            hl,
            format!(
                "$Nodes header says {} nodes, blocks hold {}",
                head[1],
                out.positions.len()
            ),
        ));
    }
    end_section(cur, "$EndNodes")?;
    Ok(out)
}

fn nodes_22(cur: &mut Cursor) -> Result<RawNodes, MeshError> {
    let (hl, h) = cur.expect("the node count")?;
    let head = cur.ints(hl, h, "node count")?;
    if head.len() != 1 || head[0] < 0 {
        return Err(cur.err(hl, "$Nodes must start with the node count"));
    }
    let n = head[0] as usize;
    let mut out = RawNodes {
        positions: Vec::with_capacity(reserve(n as i64)),
        tag_to_index: HashMap::with_capacity(reserve(n as i64)),
    };
    for _ in 0..n {
        let (l, t) = cur.expect("a node line")?;
        let parts: Vec<&str> = t.split_whitespace().collect();
        let tag: i64 = parts[0]
            .parse()
            .map_err(|_| cur.err(l, format!("node tag `{}` is not an integer", parts[0])))?;
        push_node(cur, &mut out, l, tag, &parts[1..])?;
    }
    end_section(cur, "$EndNodes")?;
    Ok(out)
}

fn elements_41(cur: &mut Cursor) -> Result<Vec<RawElement>, MeshError> {
    let (hl, h) = cur.expect("the $Elements header")?;
    let head = cur.ints(hl, h, "$Elements header")?;
    if head.len() != 4 || head.iter().any(|&v| v < 0) {
        return Err(cur.err(
            hl,
            "$Elements header must be `numEntityBlocks numElements minElementTag maxElementTag`",
        ));
    }
    let mut out = Vec::with_capacity(reserve(head[1]));
    for _ in 0..head[0] {
        let (bl, b) = cur.expect("an element block header")?;
        let block = cur.ints(bl, b, "element block header")?;
        if block.len() != 4 || block[3] < 0 {
            return Err(cur.err(
                bl,
                "element block header must be `entityDim entityTag elementType numElementsInBlock`",
            ));
        }
        let kind = block[2];
        for _ in 0..block[3] {
            let (l, t) = cur.expect("an element line")?;
            let v = cur.ints(l, t, "element")?;
            if v.is_empty() {
                return Err(cur.err(l, "empty element line"));
            }
            out.push(RawElement {
                tag: v[0],
                line: l,
                kind,
                nodes: v[1..].to_vec(),
            });
        }
    }
    if out.len() != head[1] as usize {
        return Err(cur.err(
            hl,
            format!(
                "$Elements header says {} elements, blocks hold {}",
                head[1],
                out.len()
            ),
        ));
    }
    end_section(cur, "$EndElements")?;
    Ok(out)
}

fn elements_22(cur: &mut Cursor) -> Result<Vec<RawElement>, MeshError> {
    let (hl, h) = cur.expect("the element count")?;
    let head = cur.ints(hl, h, "element count")?;
    if head.len() != 1 || head[0] < 0 {
        return Err(cur.err(hl, "$Elements must start with the element count"));
    }
    let mut out = Vec::with_capacity(reserve(head[0]));
    for _ in 0..head[0] {
        let (l, t) = cur.expect("an element line")?;
        let v = cur.ints(l, t, "element")?;
        // tag type ntags tag... node...
        if v.len() < 3 || v[2] < 0 || v.len() < 3 + v[2] as usize {
            return Err(cur.err(
                l,
                "element line must be `tag type numTags tags... nodes...`",
            ));
        }
        out.push(RawElement {
            tag: v[0],
            line: l,
            kind: v[1],
            nodes: v[3 + v[2] as usize..].to_vec(),
        });
    }
    end_section(cur, "$EndElements")?;
    Ok(out)
}
